use clap::Parser;

fn main() {
    let cli = gscodec::cli::Cli::parse();
    if let Err(e) = gscodec::cli::run(cli) {
        eprintln!("error: {e}");
        std::process::exit(e.exit_code());
    }
}
