# Sourced by the setup scripts: `apt_ensure NAME PACKAGE...` installs the Debian packages that
# are not installed yet, and does nothing (and prints nothing) when all are. Works as root on
# a fresh Debian/Ubuntu without sudo, and uses sudo when run as another user. `apt-get update`
# runs only when the install fails for lack of package lists. NAME prefixes its messages.

apt_ensure() {
    local name="$1"
    shift
    local missing=() p
    for p in "$@"; do
        if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
            missing+=("$p")
        fi
    done
    [ ${#missing[@]} -eq 0 ] && return 0

    if ! command -v apt-get >/dev/null 2>&1; then
        echo "$name: apt-get not found; install ${missing[*]} by hand" >&2
        return 1
    fi
    local sudo=()
    if [ "$(id -u)" -ne 0 ]; then
        if command -v sudo >/dev/null 2>&1; then
            sudo=(sudo)
        else
            echo "$name: not root and no sudo; cannot install ${missing[*]}" >&2
            return 1
        fi
    fi
    echo "$name: installing ${missing[*]}"
    if ! "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null 2>&1; then
        echo "$name: package lists stale or missing; running apt-get update"
        "${sudo[@]}" apt-get update -qq
        "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    fi
    echo "$name: done"
}
