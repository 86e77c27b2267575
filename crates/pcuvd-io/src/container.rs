//! What a file is, from its first bytes: [`sniff`] recognises the containers pcuvd reads (NumPy
//! `.npy` and `.npz`, MATLAB v5, HDF5 behind any user block, a recording manifest), and
//! [`read_head`] reads those bytes with a message that says what a path is when it is not a file.
//! Both the format detection ([`crate::open`]) and the samples files ([`crate::datafile`]) use it.

use std::path::Path;

use crate::error::IoError;

/// What the first bytes of a file say it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Container {
    /// A NumPy `.npy` array (`\x93NUMPY`).
    Npy,
    /// A zip archive (NumPy `.npz`).
    Zip,
    /// A MATLAB v5/v7 MAT-file (text header, version 0x0100).
    MatV5,
    /// An HDF5 file whose superblock is at `offset` (0, or 512, 1024... after a user block:
    /// MATLAB v7.3 writes 512).
    Hdf5 {
        /// Bytes of user block before the superblock.
        offset: u64,
    },
    /// Text that reads as a pcuvd recording manifest (TOML).
    Manifest,
}

const HDF5_SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// Recognises a file from its first bytes (`head`, at least the first 8 KiB when the file has
/// them); `None` when nothing pcuvd reads starts that way.
pub fn sniff(head: &[u8]) -> Option<Container> {
    if head.starts_with(b"\x93NUMPY") {
        return Some(Container::Npy);
    }
    if head.starts_with(b"PK\x03\x04") || head.starts_with(b"PK\x05\x06") {
        return Some(Container::Zip);
    }
    let mut offset = 0usize;
    while offset + 8 <= head.len() {
        if &head[offset..offset + 8] == HDF5_SIGNATURE {
            return Some(Container::Hdf5 {
                offset: offset as u64,
            });
        }
        offset = if offset == 0 { 512 } else { offset * 2 };
    }
    if head.len() >= 128 && head.starts_with(b"MATLAB") {
        let version = &head[124..126];
        if version == [0x00, 0x01] || version == [0x01, 0x00] {
            return Some(Container::MatV5);
        }
    }
    let text = String::from_utf8_lossy(&head[..head.len().min(4096)]);
    if text.contains("pcuvd-recording") {
        return Some(Container::Manifest);
    }
    None
}

/// Reads up to the first `n` bytes of `path`, with a message that says what `path` is when it is
/// not a regular file.
pub fn read_head(path: &Path, n: usize) -> Result<Vec<u8>, IoError> {
    use std::io::Read;
    let meta = std::fs::metadata(path).map_err(|e| IoError::io(path, "read", e))?;
    if meta.is_dir() {
        return Err(IoError::io(
            path,
            "read",
            std::io::Error::new(
                std::io::ErrorKind::IsADirectory,
                "it is a folder, not a recording file (give the recording file or its manifest .toml)",
            ),
        ));
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() || t.is_socket() || t.is_char_device() || t.is_block_device() {
            return Err(IoError::malformed(
                path,
                "is a pipe, socket or device, not a recording file",
            ));
        }
    }
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, "read", e))?;
    let mut head = Vec::with_capacity(n);
    file.take(n as u64)
        .read_to_end(&mut head)
        .map_err(|e| IoError::io(path, "read", e))?;
    Ok(head)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sniffs_each_container() {
        assert_eq!(sniff(b"\x93NUMPY\x01\x00"), Some(Container::Npy));
        assert_eq!(sniff(b"PK\x03\x04rest"), Some(Container::Zip));
        let mut hdf = vec![0u8; 1024];
        hdf[512..520].copy_from_slice(HDF5_SIGNATURE);
        assert_eq!(sniff(&hdf), Some(Container::Hdf5 { offset: 512 }));
        let mut mat = b"MATLAB 5.0 MAT-file".to_vec();
        mat.resize(128, b' ');
        mat[124] = 0;
        mat[125] = 1;
        assert_eq!(sniff(&mat), Some(Container::MatV5));
        assert_eq!(
            sniff(b"format = \"pcuvd-recording\"\nversion = 1\n"),
            Some(Container::Manifest)
        );
        assert_eq!(sniff(b"hello"), None);
    }
}
