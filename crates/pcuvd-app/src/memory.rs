//! The memory check before work: a run that would need more than the machine (or the user's
//! limit) allows is refused with the amount it needs, instead of aborting on allocation.

use anyhow::{Result, bail};
use pcuvd::acquisition::source::FrameSource;
use pcuvd::pipeline;

use crate::run::{DynamicsFit, Plan};

/// How [`check_memory`] counts beyond [`pipeline::MEMORY_ESTIMATE_RULE`].
pub const STAGE_MEMORY_RULE: &str = "+ dynamics: 4 × windows × pixels × 8 bytes (vx, vz, power \
and, for vessel pooling, speed per window; 2 with one steering angle: its velocity and power) + \
time series: ensembles × pixels × 6 × 8 bytes (five maps and a filtered copy of one ensemble's \
frames per angle counted once more) + sites: sites × frames × angles × 8 bytes (each site's \
filtered series over the whole recording)";

/// Bytes the stages after image formation hold beyond the image series ([`STAGE_MEMORY_RULE`]:
/// the dynamics windows, the time series) in a run planned by `plan` of a recording of `frames`
/// frames of `n_angles` angles.
pub fn stage_memory_of(plan: &Plan, frames: usize, n_angles: usize) -> u128 {
    dynamics_memory(plan, (frames, n_angles))
        + ensembles_memory(plan, frames, n_angles)
        + kept_memory(plan, frames, n_angles)
}

/// Bytes the dynamics stage's windows of the whole recording hold ([`STAGE_MEMORY_RULE`]):
/// none when the stage is off or no window fits in the recording's `frames`.
fn dynamics_memory(plan: &Plan, shape: (usize, usize)) -> u128 {
    plan.dynamics
        .as_ref()
        .map_or(0, |d| windows_memory(plan, shape, d.params.step))
}

/// Bytes the dynamics windows of `plan`, for a recording of `frames` frames of `n_angles`
/// angles, hold when they start `step` frames apart.
fn windows_memory(plan: &Plan, (frames, n_angles): (usize, usize), step: usize) -> u128 {
    let (nz, nx) = plan.params.grid.shape();
    // One angle's windows hold its velocity and power, and its speed is read lane by lane.
    let maps = if n_angles == 1 { 2 } else { 4 };
    plan.dynamics.as_ref().map_or(0, |d| {
        if d.params.window > frames {
            return 0;
        }
        let windows = (frames - d.params.window) / step.max(1) + 1;
        maps * windows as u128 * (nz * nx) as u128 * 8
    })
}

/// Bytes the Doppler time series hold ([`STAGE_MEMORY_RULE`]); none without ensembles.
fn ensembles_memory(plan: &Plan, frames: usize, n_angles: usize) -> u128 {
    let (nz, nx) = plan.params.grid.shape();
    let pixels = (nz * nx) as u128;
    plan.ensembles.map_or(0, |e| {
        let count = frames.saturating_sub(e.frames) / e.step.max(1) + 1;
        count as u128 * pixels * 6 * 8 + e.frames as u128 * pixels * n_angles as u128 * 8
    })
}

/// Bytes the kept pixels' filtered series hold over the whole recording ([`STAGE_MEMORY_RULE`]):
/// single-precision complex, per angle and frame.
fn kept_memory(plan: &Plan, frames: usize, n_angles: usize) -> u128 {
    plan.kept_pixels.len() as u128 * frames as u128 * n_angles as u128 * 8
}

/// Refuses, before any work, a recording, grid and stages whose processing would need more memory
/// than this process may take ([`pipeline::memory_estimate`] + [`STAGE_MEMORY_RULE`] against
/// [`memory_room`], or the user's `limit_gb`), instead of aborting on allocation. Under
/// `--dynamics auto` a run that fits without the dynamics windows spaces them further apart, or
/// drops that stage, instead ([`fit_stages`]).
pub fn check_memory(data: &dyn FrameSource, plan: &mut Plan, limit_gb: Option<f64>) -> Result<()> {
    let Some(room) = room_within(limit_gb)? else {
        return Ok(());
    };
    let chain = pipeline::memory_estimate(data, &plan.params.grid) as f64;
    let acq = data.acquisition();
    let shape = (data.n_frames(), acq.sequence.n_angles(), acq.frame_rate());
    let held = Held {
        bytes: chain,
        rule: pipeline::MEMORY_ESTIMATE_RULE,
        instead: "use a coarser or smaller --grid, or a shorter recording",
    };
    fit_stages(plan, &held, shape, &room)
}

/// What a run holds before its later stages ([`fit_stages`]): bytes, the rule that counts them,
/// and what the user can do when they alone do not fit.
struct Held {
    bytes: f64,
    rule: &'static str,
    instead: &'static str,
}

/// Checks that `held` and the later stages of `plan` (for a recording of `frames` frames of
/// `n_angles` angles at `frame_rate` (Hz), [`STAGE_MEMORY_RULE`]) fit in `room`. The dynamics
/// windows of the whole recording grow with its length (4 maps of 8 bytes per pixel per window,
/// 2 of one angle: about 31 GB, or 16, for five minutes of 128 × 128 pixels at a 5 ms step), the
/// rest of a segmented run does not: where they alone would not fit and no dynamics setting was
/// given (`--dynamics auto`), the windows start further apart, the step the fewest whole
/// multiples of the default's that fit, up to the window's length (windows side by side: the RI
/// maps read from a cycle's fitted harmonics, which a few windows per cycle hold, and on the
/// rat-network phantom they read alike at steps of 5, 10 and 20 ms); where none fits, the plan drops the stage. Either is
/// said ([`Plan::dynamics_fit`]), so that a long functional recording still gives its maps and
/// time series; with a dynamics setting the run is refused, naming `--window-step-ms` and
/// `--dynamics off`.
fn fit_stages(
    plan: &mut Plan,
    held: &Held,
    (frames, n_angles, frame_rate): (usize, usize, f64),
    room: &MemoryRoom,
) -> Result<()> {
    let windows = dynamics_memory(plan, (frames, n_angles)) as f64;
    let others = held.bytes
        + ensembles_memory(plan, frames, n_angles) as f64
        + kept_memory(plan, frames, n_angles) as f64;
    let needed = others + windows;
    if needed <= room.bytes {
        return Ok(());
    }
    let available = format!(
        "{} are available ({})",
        gigabytes(room.bytes.max(0.0)),
        room.bound
    );
    let without_windows = windows > 0.0 && others <= room.bytes;
    if without_windows && !plan.dynamics_required {
        let room_left = room.bytes - others;
        let recording = (frames, n_angles, frame_rate);
        let fit = spaced_windows(plan, recording, room_left, &available).unwrap_or_else(|| {
            DynamicsFit::Dropped(format!(
                "the dynamics windows of the whole recording would need about {} beside the \
                     run's {} (at least {} with the windows side by side), and {available}: run \
                     where more memory is free, for RI maps",
                gigabytes(windows),
                gigabytes(others),
                gigabytes(side_by_side(plan, (frames, n_angles))),
            ))
        });
        return plan.apply_fit(fit, frames);
    }
    let instead = if without_windows {
        format!(
            "the dynamics windows alone need {}: give a longer --window-step-ms, or \
             --dynamics off",
            gigabytes(windows)
        )
    } else if held.bytes <= room.bytes {
        format!(
            "the dynamics windows and Doppler time series need {}: give --dynamics off, a \
             longer --window-step-ms or fewer ensembles",
            gigabytes(needed - held.bytes)
        )
    } else {
        held.instead.to_string()
    };
    bail!(
        "processing needs about {} ({} {STAGE_MEMORY_RULE}) but {available}: {instead}",
        gigabytes(needed),
        held.rule,
    )
}

/// The dynamics windows of `plan`, for a recording of `frames` frames of `n_angles` angles at
/// `frame_rate` (Hz), started the fewest whole multiples of its step apart, up to the window's
/// length, that fit in `room` bytes ([`fit_stages`]); `None` when none does.
fn spaced_windows(
    plan: &Plan,
    (frames, n_angles, frame_rate): (usize, usize, f64),
    room: f64,
    available: &str,
) -> Option<DynamicsFit> {
    let params = plan.dynamics.as_ref()?.params;
    let step_ms = |step: usize| step as f64 / frame_rate * 1e3;
    let planned = windows_memory(plan, (frames, n_angles), params.step) as f64;
    (2..)
        .map(|k| k * params.step.max(1))
        .take_while(|&step| step <= params.window)
        .find(|&step| windows_memory(plan, (frames, n_angles), step) as f64 <= room)
        .map(|step| DynamicsFit::Stepped {
            step,
            reason: format!(
                "RI maps from dynamics windows every {:.1} ms rather than {:.1} ms: at {:.1} ms \
                 the windows of the whole recording would need about {}, and {available} \
                 (--window-step-ms sets the step; a recording of a few cycles would rather have \
                 its windows closer)",
                step_ms(step),
                step_ms(params.step),
                step_ms(params.step),
                gigabytes(planned),
            ),
        })
}

/// Bytes the dynamics windows of `plan` hold side by side (started a window's length apart,
/// the furthest [`spaced_windows`] spaces them).
fn side_by_side(plan: &Plan, shape: (usize, usize)) -> f64 {
    let window = plan.dynamics.as_ref().map_or(1, |d| d.params.window);
    windows_memory(plan, shape, window) as f64
}

/// The memory a run may use: `--max-memory-gb` when given (checked), else what the machine
/// and the process's limits leave ([`memory_room`]).
fn room_within(limit_gb: Option<f64>) -> Result<Option<MemoryRoom>> {
    Ok(match limit_gb {
        Some(gb) if gb.is_finite() && gb > 0.0 => Some(MemoryRoom {
            bytes: gb * 1e9,
            bound: format!(
                "--max-memory-gb {}",
                crate::settings::shown("--max-memory-gb", gb)
            ),
        }),
        Some(gb) => bail!(
            "--max-memory-gb {}: must be a positive number of GB",
            crate::settings::shown("--max-memory-gb", gb)
        ),
        None => memory_room(),
    })
}

/// How a run on images formed elsewhere is sized: their frames held at once (all of them, or a
/// segment's).
pub const IMAGES_MEMORY_RULE: &str = "three times the images held at once as complex64 (all \
their frames, or one segment's with its overlap): an angle's frames as read, the per-angle \
series (filtered in place) and their compound";

/// Refuses, before they are read, beamformed images at `frame_rate` (Hz) of which `bytes` (as
/// complex64) are held at once (all their `frames`, or a segment's when `plan` cuts them) that a
/// run could not hold ([`IMAGES_MEMORY_RULE`]) with its later stages ([`STAGE_MEMORY_RULE`], [`fit_stages`])
/// within `limit_gb` or what the machine leaves.
pub fn check_images_memory(
    plan: &mut Plan,
    (bytes, frames, n_angles, frame_rate): (u64, usize, usize, f64),
    limit_gb: Option<f64>,
) -> Result<()> {
    let Some(room) = room_within(limit_gb)? else {
        return Ok(());
    };
    let held = Held {
        bytes: 3.0 * bytes as f64,
        rule: IMAGES_MEMORY_RULE,
        instead: match plan.segments.is_some() {
            true => "give a smaller --segment-frames",
            false => "give --segment-frames to hold fewer frames at once",
        },
    };
    fit_stages(plan, &held, (frames, n_angles, frame_rate), &room)
}

/// Refuses work that would hold `bytes` in memory where less may still be allocated
/// ([`memory_room`]): `what` is what would be held, `instead` what the user can do.
pub fn check_room_for(bytes: u64, what: &str, instead: &str) -> Result<()> {
    if let Some(room) = memory_room()
        && bytes as f64 > room.bytes
    {
        bail!(
            "{what} need about {} but {} are available ({}): {instead}",
            gigabytes(bytes as f64),
            gigabytes(room.bytes.max(0.0)),
            room.bound
        );
    }
    Ok(())
}

/// `bytes` in GB for a message: three decimals up to 10 GB, whole GB beyond.
pub fn gigabytes(bytes: f64) -> String {
    let gb = bytes / 1e9;
    if gb < 10.0 {
        format!("{gb:.3} GB")
    } else {
        format!("{gb:.0} GB")
    }
}

/// Bytes this process may still write on the file system that holds `path` (an existing
/// folder), where the system says: statvfs on Unix, GetDiskFreeSpaceExW on Windows.
pub fn free_disk_space(path: &std::path::Path) -> Option<u64> {
    #[cfg(unix)]
    {
        let stats = rustix::fs::statvfs(path).ok()?;
        Some(stats.f_bavail.saturating_mul(stats.f_frsize))
    }
    #[cfg(not(unix))]
    {
        fs4::available_space(path).ok()
    }
}

/// Memory a run may still take (bytes), and what bounds it.
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryRoom {
    /// Bytes that may still be allocated (negative when the process is already past a limit).
    pub bytes: f64,
    /// What sets it, in the user's words ("the machine", "the address-space limit (ulimit -v)
    /// of 1.500 GB, 0.120 GB in use"...).
    pub bound: String,
}

/// The tightest bound on what this process may still allocate: the machine's available memory,
/// the address-space limit (RLIMIT_AS, `ulimit -v`) less the process's virtual size, the data
/// limit (RLIMIT_DATA) less its data segment, and its control group's `memory.max` (v2) or
/// `memory.limit_in_bytes` (v1) less what the group uses. A batch scheduler's limit is one of
/// these: without them a run that the machine could hold aborts on a failed allocation.
pub fn memory_room() -> Option<MemoryRoom> {
    let gb = |b: f64| b / 1e9;
    let mut bounds: Vec<MemoryRoom> = Vec::new();
    if let Some(available) = available_memory() {
        bounds.push(MemoryRoom {
            bytes: available as f64,
            bound: "the machine".into(),
        });
    }
    // Resource limits are Unix's (a Windows job's limit is not read).
    #[cfg(unix)]
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    #[cfg(unix)]
    for (resource, field, name) in [
        (
            rlimit::Resource::AS,
            "VmSize:",
            "address-space limit (ulimit -v)",
        ),
        (
            rlimit::Resource::DATA,
            "VmData:",
            "data-segment limit (ulimit -d)",
        ),
    ] {
        if let Ok((soft, _)) = resource.get()
            && soft != rlimit::INFINITY
        {
            let used = status_kib(&status, field).map_or(0.0, |kib| kib as f64 * 1024.0);
            bounds.push(MemoryRoom {
                bytes: soft as f64 - used,
                bound: format!(
                    "the process's {name} of {:.3} GB, {:.3} GB of it in use",
                    gb(soft as f64),
                    gb(used)
                ),
            });
        }
    }
    if let Some((limit, used)) = cgroup_memory() {
        bounds.push(MemoryRoom {
            bytes: limit - used,
            bound: format!(
                "the control group's memory limit of {:.3} GB, {:.3} GB of it in use",
                gb(limit),
                gb(used)
            ),
        });
    }
    bounds
        .into_iter()
        .min_by(|a, b| a.bytes.total_cmp(&b.bytes))
}

/// A `Name:  N kB` line of /proc/self/status or /proc/meminfo (kibibytes).
#[cfg(unix)]
fn status_kib(status: &str, field: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with(field))?;
    line[field.len()..].split_whitespace().next()?.parse().ok()
}

/// This process's control group's memory limit and use (bytes), when it has a limit: cgroup v2's
/// `memory.max` and `memory.current`, else v1's `memory.limit_in_bytes` and `memory.usage_in_bytes`.
fn cgroup_memory() -> Option<(f64, f64)> {
    let groups = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    let read =
        |path: String| -> Option<f64> { std::fs::read_to_string(path).ok()?.trim().parse().ok() };
    for line in groups.lines() {
        let mut parts = line.splitn(3, ':');
        let (_, controllers, path) = (parts.next()?, parts.next()?, parts.next()?);
        let path = path.trim_end_matches('/');
        if controllers.is_empty() {
            let dir = format!("/sys/fs/cgroup{path}");
            if let (Some(limit), Some(used)) = (
                read(format!("{dir}/memory.max")),
                read(format!("{dir}/memory.current")),
            ) {
                return Some((limit, used));
            }
        } else if controllers.split(',').any(|c| c == "memory") {
            let dir = format!("/sys/fs/cgroup/memory{path}");
            let limit = read(format!("{dir}/memory.limit_in_bytes"))?;
            // v1 writes "no limit" as a number near 2^63.
            if limit < 1e18 {
                return Some((limit, read(format!("{dir}/memory.usage_in_bytes"))?));
            }
        }
    }
    None
}

/// Memory available to a new process (bytes): `MemAvailable` of /proc/meminfo on Linux, what
/// the system reports as available elsewhere (macOS, Windows).
pub fn available_memory() -> Option<u64> {
    #[cfg(target_os = "linux")]
    {
        let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
        status_kib(&meminfo, "MemAvailable:").map(|kib| kib * 1024)
    }
    #[cfg(not(target_os = "linux"))]
    {
        use sysinfo::{MemoryRefreshKind, RefreshKind, System};
        let system = System::new_with_specifics(
            RefreshKind::nothing().with_memory(MemoryRefreshKind::nothing().with_ram()),
        )
        .ok()?;
        // Zero is what sysinfo reports where it could not read the memory.
        Some(system.available_memory()).filter(|&bytes| bytes > 0)
    }
}

/// Peak resident memory of this process so far (bytes): `VmHWM` of /proc/self/status on Linux,
/// getrusage's `ru_maxrss` on macOS, the peak working set on Windows; `None` elsewhere. From
/// Python it is the interpreter's peak, the run's included.
pub fn peak_resident_memory() -> Option<u64> {
    #[cfg(target_os = "linux")]
    {
        let status = std::fs::read_to_string("/proc/self/status").ok()?;
        status_kib(&status, "VmHWM:").map(|kib| kib * 1024)
    }
    #[cfg(target_os = "macos")]
    {
        // SAFETY: getrusage writes one rusage into the zeroed struct it is given, nothing else.
        let usage = unsafe {
            let mut usage: libc::rusage = std::mem::zeroed();
            (libc::getrusage(libc::RUSAGE_SELF, &mut usage) == 0).then_some(usage)
        }?;
        // macOS counts ru_maxrss in bytes (Linux and the BSDs in KiB).
        u64::try_from(usage.ru_maxrss).ok()
    }
    #[cfg(windows)]
    {
        use windows_sys::Win32::System::ProcessStatus::{
            GetProcessMemoryInfo, PROCESS_MEMORY_COUNTERS,
        };
        use windows_sys::Win32::System::Threading::GetCurrentProcess;
        let mut counters = PROCESS_MEMORY_COUNTERS {
            cb: std::mem::size_of::<PROCESS_MEMORY_COUNTERS>() as u32,
            ..Default::default()
        };
        // SAFETY: the call writes `cb` bytes into `counters`, which holds them; the handle is
        // the pseudo-handle of this process, never closed.
        let done = unsafe { GetProcessMemoryInfo(GetCurrentProcess(), &mut counters, counters.cb) };
        (done != 0).then_some(counters.PeakWorkingSetSize as u64)
    }
    #[cfg(not(any(target_os = "linux", target_os = "macos", windows)))]
    {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::{DynamicsSettings, ProcessingSettings};

    /// Each site keeps its pixel's filtered series over the whole recording: the stages'
    /// estimate grows by sites × frames × angles × 8 bytes, which a long recording makes
    /// megabytes a site.
    #[test]
    fn each_site_adds_its_series_to_the_estimate() {
        let data = pcuvd_testing::tube_recording(false, 4);
        let plan = |sites: Option<&str>| {
            let options = ProcessingSettings {
                grid: Some("-1,1,5,7,0.05".into()),
                sites: sites.map(str::to_string),
                ..ProcessingSettings::default()
            };
            let dynamics = DynamicsSettings {
                dynamics: crate::settings::DynamicsChoice::Off,
                ..DynamicsSettings::default()
            };
            Plan::new(&options, &dynamics, &data, None).unwrap()
        };
        let (without, with) = (plan(None), plan(Some("0,6;0.5,6.5;-0.5,5.5")));
        assert_eq!(with.kept_pixels.len(), 3);
        // Five minutes at 1 kHz of eight angles: 19.2 MB a site.
        let (frames, angles) = (300_000, 8);
        assert_eq!(
            stage_memory_of(&with, frames, angles) - stage_memory_of(&without, frames, angles),
            3 * 300_000 * 8 * 8
        );
    }
}
