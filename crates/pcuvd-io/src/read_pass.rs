//! A file's bytes handed, in order and once each, to a checksum as a reader's blocks pass over
//! them: the input is identified without a second read of the whole file.
//!
//! A reader offers each range of its file it has just read ([`ReadPass::offer`]). Blocks may
//! arrive in any order and may overlap (ensembles share margins): what was fed is skipped, and a
//! range no block covered before a later one (the file's header, frames the run skipped) is read
//! from the file to fill the gap, so the sink always sees bytes `0..len` exactly once, in order.
//! [`ReadPass::finish`] feeds what no block reached.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// A checksum being computed: fed every byte of a file, in order.
pub trait ChecksumSink: Send {
    /// Takes the next `bytes` of the file.
    fn update(&mut self, bytes: &[u8]);
    /// The checksum of all the bytes fed, in hexadecimal.
    fn hex(self: Box<Self>) -> String;
}

/// A file identified in a reader's pass: its size and checksum, and the time spent on them.
#[derive(Debug, Clone, PartialEq)]
pub struct Checksummed {
    /// The file's size (bytes).
    pub size_bytes: u64,
    /// Its checksum (hex).
    pub hex: String,
    /// Seconds spent hashing, and reading what no block read.
    pub seconds: f64,
}

/// Bytes read at a time when a gap (or, with no block offered, the whole file) is read.
const GAP_PIECE: usize = 8 << 20;

/// A sink being fed and how far into the file it has been fed (bytes).
struct Feeding {
    sink: Box<dyn ChecksumSink>,
    fed_to: u64,
    seconds: f64,
    /// The first error of a gap's read, reported by [`ReadPass::finish`].
    failed: Option<std::io::Error>,
}

/// The hook through which a block reader feeds its samples file to a checksum: shared between
/// the reader (which offers what it reads) and whoever attached a sink (which finishes it).
/// Idle until a sink is attached.
#[derive(Clone)]
pub struct ReadPass {
    path: PathBuf,
    feeding: Arc<Mutex<Option<Feeding>>>,
}

impl std::fmt::Debug for ReadPass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReadPass")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

impl ReadPass {
    /// A pass over the file at `path`, with no sink yet.
    pub fn new(path: &Path) -> ReadPass {
        ReadPass {
            path: path.to_path_buf(),
            feeding: Arc::default(),
        }
    }

    /// The file whose bytes the pass feeds.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Starts feeding `sink` from the file's first byte, with the blocks read from now on.
    pub fn attach(&self, sink: Box<dyn ChecksumSink>) {
        *self.lock() = Some(Feeding {
            sink,
            fed_to: 0,
            seconds: 0.0,
            failed: None,
        });
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Option<Feeding>> {
        // A panic while feeding leaves a sink no worse than unfinished; finish reports the rest.
        self.feeding.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Hands the attached sink `bytes`, which the reader has just read at `offset` in the file:
    /// the part not yet fed, after the gap before it (read from the file). Without a sink,
    /// nothing.
    pub fn offer(&self, offset: u64, bytes: &[u8]) {
        let mut guard = self.lock();
        let Some(feeding) = guard.as_mut() else {
            return;
        };
        if feeding.failed.is_some() {
            return;
        }
        let clock = std::time::Instant::now();
        if offset > feeding.fed_to
            && let Err(e) = feed_from_file(&self.path, feeding, offset)
        {
            feeding.failed = Some(e);
            return;
        }
        let end = offset + bytes.len() as u64;
        if end > feeding.fed_to {
            let new = (feeding.fed_to - offset) as usize;
            feeding.sink.update(&bytes[new..]);
            feeding.fed_to = end;
        }
        feeding.seconds += clock.elapsed().as_secs_f64();
    }

    /// Feeds the sink the rest of the file (what no block reached) and gives its checksum with
    /// the file's size; `Ok(None)` when no sink was attached.
    pub fn finish(&self) -> std::io::Result<Option<Checksummed>> {
        let Some(mut feeding) = self.lock().take() else {
            return Ok(None);
        };
        let clock = std::time::Instant::now();
        if let Some(e) = feeding.failed.take() {
            return Err(e);
        }
        let len = std::fs::metadata(&self.path)?.len();
        if feeding.fed_to > len {
            return Err(std::io::Error::other(
                "the file became shorter while it was read",
            ));
        }
        feed_from_file(&self.path, &mut feeding, len)?;
        let hex = feeding.sink.hex();
        Ok(Some(Checksummed {
            size_bytes: len,
            hex,
            seconds: feeding.seconds + clock.elapsed().as_secs_f64(),
        }))
    }
}

/// Feeds `feeding` the file's bytes from where it stands to `to`.
fn feed_from_file(path: &Path, feeding: &mut Feeding, to: u64) -> std::io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    if to <= feeding.fed_to {
        return Ok(());
    }
    let mut file = std::fs::File::open(path)?;
    file.seek(SeekFrom::Start(feeding.fed_to))?;
    let mut buffer = vec![0u8; GAP_PIECE.min((to - feeding.fed_to) as usize)];
    while feeding.fed_to < to {
        let n = buffer.len().min((to - feeding.fed_to) as usize);
        file.read_exact(&mut buffer[..n])?;
        feeding.sink.update(&buffer[..n]);
        feeding.fed_to += n as u64;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sink that keeps what it was fed, to compare with the file.
    struct Kept(Arc<Mutex<Vec<u8>>>);

    impl ChecksumSink for Kept {
        fn update(&mut self, bytes: &[u8]) {
            self.0.lock().unwrap().extend_from_slice(bytes);
        }
        fn hex(self: Box<Self>) -> String {
            format!("{} bytes", self.0.lock().unwrap().len())
        }
    }

    fn file_of(len: usize) -> (tempfile::TempDir, PathBuf, Vec<u8>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("samples.npy");
        // Not periodic, so that a range fed twice or skipped cannot go unnoticed.
        let bytes: Vec<u8> = (0..len as u64)
            .map(|i| (i.wrapping_mul(2654435761) >> 13) as u8)
            .collect();
        std::fs::write(&path, &bytes).unwrap();
        (dir, path, bytes)
    }

    /// What a sink attached to a pass over a file sees when the reader offers `ranges`.
    fn fed(bytes: &[u8], path: &Path, ranges: &[std::ops::Range<usize>]) -> Vec<u8> {
        let pass = ReadPass::new(path);
        let kept = Arc::new(Mutex::new(Vec::new()));
        pass.attach(Box::new(Kept(kept.clone())));
        for r in ranges {
            pass.offer(r.start as u64, &bytes[r.clone()]);
        }
        let done = pass.finish().unwrap().unwrap();
        assert_eq!(done.size_bytes, bytes.len() as u64);
        assert_eq!(done.hex, format!("{} bytes", bytes.len()));
        Arc::try_unwrap(kept).unwrap().into_inner().unwrap()
    }

    #[test]
    fn every_byte_reaches_the_sink_once_in_order_whatever_the_blocks() {
        let (_dir, path, bytes) = file_of(20_000_000);
        let cases: [&[std::ops::Range<usize>]; 6] = [
            // Blocks after a header, in order.
            &[128..5_000_128, 5_000_128..20_000_000],
            // Overlapping ensembles, the file's tail never read.
            &[
                128..9_000_000,
                7_000_000..15_000_000,
                14_000_000..18_000_000,
            ],
            // Out of order, a block read twice, and one within what was fed.
            &[
                10_000_000..12_000_000,
                0..3_000_000,
                10_000_000..12_000_000,
                11_000_000..19_000_000,
            ],
            // Nothing read by blocks at all: the whole file at finish, in gap pieces.
            &[],
            // A block, then the whole file at once over it.
            &[0..10_000_000, 0..20_000_000],
            // An empty block in the middle.
            &[0..10, 500..500, 400..20_000_000],
        ];
        for ranges in cases {
            assert!(fed(&bytes, &path, ranges) == bytes, "{ranges:?}");
        }
    }

    #[test]
    fn an_idle_pass_feeds_nothing_and_blocks_read_before_attaching_are_read_again() {
        let (_dir, path, bytes) = file_of(1000);
        let pass = ReadPass::new(&path);
        pass.offer(0, &bytes[..600]);
        assert!(pass.finish().unwrap().is_none());
        let kept = Arc::new(Mutex::new(Vec::new()));
        pass.attach(Box::new(Kept(kept.clone())));
        pass.offer(600, &bytes[600..]);
        pass.finish().unwrap().unwrap();
        assert!(*kept.lock().unwrap() == bytes);
    }

    #[test]
    fn a_file_that_shrank_is_an_error_not_a_checksum() {
        let (_dir, path, bytes) = file_of(1000);
        let pass = ReadPass::new(&path);
        pass.attach(Box::new(Kept(Arc::default())));
        pass.offer(0, &bytes);
        std::fs::write(&path, &bytes[..500]).unwrap();
        assert!(pass.finish().is_err());
        // A gap that cannot be read any more is reported at finish.
        pass.attach(Box::new(Kept(Arc::default())));
        pass.offer(800, &bytes[800..]);
        assert!(pass.finish().is_err());
    }
}
