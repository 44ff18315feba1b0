//! The `biscale` executable: see `biscale --help`, and the library of this crate.

fn main() -> std::process::ExitCode {
    biscale_cli::main()
}
