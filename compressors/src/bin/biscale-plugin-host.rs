//! The child process of an isolated compressor plugin (`isolate = true`) for programs whose
//! own `main` does not serve the plugin protocol: tests, and library users, who name it in
//! `IsolateOptions::host` or the `BISCALE_PLUGIN_HOST` variable. The `biscale` binary serves
//! the protocol itself and does not need it. Started by hand it explains itself and exits.

fn main() -> std::process::ExitCode {
    biscale_compressors::plugin::serve_if_child();
    eprintln!(
        "biscale-plugin-host runs a compressor plugin in a child process for biscale (isolate = true); \
         it is started by biscale, not by hand"
    );
    std::process::ExitCode::from(2)
}
