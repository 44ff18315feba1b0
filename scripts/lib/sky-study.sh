# Sourced by the studies against Mitsuba 3 under the bundled skies (texel-directions-study.sh,
# resolve-energy-study.sh, sun-irradiance-study.sh), from the checkout's root:
#   study_setup NAME [SKY...]
# builds the release `biscale` and sets `root` (the checkout), `out` (out/NAME, made), `B` (the
# binary), `PY` (the .venv's Python, with Mitsuba: scripts/setup-python.sh --mitsuba) and the
# array `skies` (the SKYs given, else the four bundled skies with a sun).
study_setup() {
    local name=$1
    shift
    root=$PWD
    out=$root/out/$name
    mkdir -p "$out"
    cargo build --release --locked -p biscale-cli --bin biscale
    B=$root/target/release/biscale
    PY=$root/.venv/bin/python
    skies=("$@")
    [ ${#skies[@]} -gt 0 ] || skies=(blender_forest blender_sunset blender_courtyard pmndrs_apartment)
}
