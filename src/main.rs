use clap::Parser;

fn main() {
    // Behave like a Unix filter: a closed pipe (`gscodec eval … | head`) ends the process quietly
    // instead of making `println!` panic.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    gscodec::cli::keep_freed_memory();
    let cli = gscodec::cli::Cli::parse();
    if let Err(e) = gscodec::cli::run(cli) {
        eprintln!("error: {e}");
        std::process::exit(e.exit_code());
    }
}
