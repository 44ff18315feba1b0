//! The argument definitions themselves (clap), which no run of the executable shows.

use biscale_cli::Cli;
use clap::CommandFactory;

/// Every argument of every command has help text, and every leaf command an example.
#[test]
fn every_argument_has_help_and_every_command_an_example() {
    fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
        let path = format!("{path} {}", cmd.get_name());
        for arg in cmd.get_arguments() {
            let builtin = matches!(arg.get_id().as_str(), "help" | "version");
            if !builtin && arg.get_help().is_none() && arg.get_long_help().is_none() {
                missing.push(format!("{path}: argument {}", arg.get_id()));
            }
        }
        let subs: Vec<_> = cmd.get_subcommands().filter(|s| s.get_name() != "help").collect();
        if subs.is_empty() && path != " biscale" {
            let example = cmd.get_after_help().map(|h| h.to_string()).unwrap_or_default();
            if !example.contains("Example: biscale") {
                missing.push(format!("{path}: no example"));
            }
        }
        for sub in subs {
            walk(sub, &path, missing);
        }
    }
    let mut missing = vec![];
    walk(&Cli::command(), "", &mut missing);
    assert!(missing.is_empty(), "missing help:\n{}", missing.join("\n"));
}
