//! The `helmcap` command line: parses the arguments and runs the command.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    cli::init_logging(args.verbose);
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line: the error and its causes, outermost first, each once (a library
            // error that prints its cause also hands it on as its source).
            let mut text = String::new();
            for cause in e.chain() {
                let t = cause.to_string();
                if !text.contains(&t) {
                    if !text.is_empty() {
                        text.push_str(": ");
                    }
                    text.push_str(&t);
                }
            }
            eprintln!("error: {text}");
            std::process::ExitCode::FAILURE
        }
    }
}
