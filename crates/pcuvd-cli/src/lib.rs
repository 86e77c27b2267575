//! The `pcuvd` command: its subcommands' arguments (the application layer's settings, as
//! options), progress bars, Ctrl-C, and what it prints. The settings, the run and its outputs
//! are [`pcuvd_app`]'s, which every front end shares.

#![warn(missing_docs)]

pub mod bench;
pub mod dealias_study;
pub mod info;
pub mod network_study;
mod numbers;
pub mod paper;
pub mod process;
pub mod progress;
pub mod simulate;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Pulse-coded ultrafast vector Doppler (PC-UVD) and conventional UVD, from channel data to velocity vectors.
#[derive(Parser)]
#[command(name = "pcuvd", version, about, long_about = None)]
struct Cli {
    /// No progress reports on stderr (errors and notes still print).
    #[arg(long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Process a recording (any format `pcuvd info` reads: MUST, USTB UFF, zea, Verasonics, URX, pcuvd manifest) into B-mode, power, colour and vector Doppler maps.
    Process(Box<process::ProcessArgs>),
    /// Simulate RF recordings (manifest + .npy) of a flow phantom, conventional and/or Hadamard-coded, with ground truth.
    Simulate(simulate::SimulateArgs),
    /// Show what pcuvd understood of a recording (format, shapes, acquisition, derived rates, memory), without processing it.
    Info(info::InfoArgs),
    /// Time each stage on a recording and report its throughput beside its bound (memory bandwidth; the beamformer's points/s beside its arithmetic bound), naming the CPU: a speed report to run by hand in a release build.
    ///
    /// With PCUVD_SIMD=avx2 (or portable) in its environment, every pcuvd kernel uses those vector instructions where the CPU has wider ones: what a CPU without AVX-512 would spend (the libraries' matrix products and checksum choose their own). PCUVD_BEAMFORM_KERNEL=avx2 (or portable) does so for the beamformer alone.
    Bench(bench::BenchArgs),
    /// Reproduce the PC-UVD paper's studies (spiral flow, vessel network, the virtual rat brain; and vector dealiasing beyond the paper): simulate, process, compare with truth; figures, metrics.json, report.html.
    Paper(paper::PaperArgs),
}

/// Runs the `pcuvd` command on the process's own arguments; the exit code to return.
pub fn main() -> ExitCode {
    // A reader that closes the pipe early (`pcuvd info … | head`) ends the process quietly, as
    // it does any Unix tool (Rust ignores SIGPIPE, and the next line printed would panic), and,
    // as Ctrl-C does, without leaving the temporary files of writes in progress.
    #[cfg(unix)]
    // SAFETY: installing a handler at start-up, before any thread runs.
    unsafe {
        libc::signal(
            libc::SIGPIPE,
            on_closed_pipe as extern "C" fn(libc::c_int) as libc::sighandler_t,
        );
    }
    keep_freed_memory();
    let cli = Cli::parse();
    progress::set_quiet(cli.quiet);
    // Ctrl-C stops at once. Every output is written under a temporary name and renamed when
    // complete, and summary.json / metrics.json / manifests come last, so what is left looks
    // incomplete; the temporary files of writes in progress are removed.
    let _ = ctrlc::set_handler(|| {
        pcuvd_io::remove_partial_files();
        eprintln!(
            "interrupted: stopped before the end; what was written is incomplete (summary.json, \
             metrics.json and manifests are written last)"
        );
        std::process::exit(130);
    });
    let result = match cli.command {
        Command::Process(args) => process::run(&args),
        Command::Simulate(args) => simulate::run(&args),
        Command::Paper(args) => paper::run(&args),
        Command::Info(args) => info::run(&args),
        Command::Bench(args) => bench::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {}", one_line(&error));
            ExitCode::from(ERROR_EXIT_CODE)
        }
    }
}

/// Keeps memory the process frees for its next allocations instead of handing it back to the
/// system at once: the dynamics windows allocate and free the same maps window after window, and
/// memory handed back is faulted in and zeroed again at its next use (in a virtual machine whose
/// host takes freed pages back, at well under a gigabyte a second). A default run of the 360 coded
/// rat-network frames spent about a second less of system time (docs/results/speed.md). Blocks up
/// to 32 MiB (glibc's largest threshold) come from the heap, which is trimmed only past 2 GiB of
/// free memory at its top; larger ones (image series, blocks of events) are mapped and unmapped as
/// before, so the run's peak memory stays what it was.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets the allocator's parameters; called at start-up, before any
    // thread runs.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, libc::c_int::MAX);
    }
}

/// Removes the temporary files of writes in progress, then ends the process by SIGPIPE, as the
/// signal's default would have. SIGPIPE is raised in the thread whose write met the closed pipe,
/// inside that write (a line printed), never inside the allocator or the list of those files,
/// so the removal runs as it would anywhere else in that thread.
#[cfg(unix)]
extern "C" fn on_closed_pipe(_: libc::c_int) {
    pcuvd_io::remove_partial_files();
    // SAFETY: restoring the default disposition and raising the signal again, which is blocked
    // until this handler returns and then ends the process.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        libc::raise(libc::SIGPIPE);
    }
}

/// Exit code of a command refused or failed for its input (the file, a field, an option), as for
/// a usage error: 2. (0: success; 130: interrupted.)
pub const ERROR_EXIT_CODE: u8 = 2;

pub use pcuvd_app::one_line;
