mod app;
mod cli;

use clap::Parser;

fn main() {
    let args = cli::Cli::parse();
    if let Err(e) = cli::run(args) {
        eprintln!("error: {}", cli::error_text(&e));
        std::process::exit(cli::exit_status(&e));
    }
}
