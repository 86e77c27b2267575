//! `pcuvd`: simulate, process and quantify ultrafast vector Doppler acquisitions.

fn main() -> std::process::ExitCode {
    pcuvd_cli::main()
}
