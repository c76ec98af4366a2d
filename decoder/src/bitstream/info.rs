//! The optional info section (SPEC §3, kind `0x100`): what the encoder's input held before
//! pruning and SH truncation. Informative: it never affects the decoded scene.

use super::{ByteReader, ByteWriter};

/// The content of an info section.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct EncoderInfo {
    /// Gaussians in the encoder's input before pruning.
    pub input_gaussians: u32,
    /// SH degree of the encoder's input.
    pub input_sh_degree: u8,
}

/// Bytes of an info section.
pub const INFO_BYTES: usize = 5;

/// Reads an info section: `u32` Gaussians, `u8` SH degree. `None` unless it is exactly 5 bytes
/// (a decoder ignores any other content, SPEC §3).
pub fn read_info(data: &[u8]) -> Option<EncoderInfo> {
    if data.len() != INFO_BYTES {
        return None;
    }
    let mut r = ByteReader::new(data);
    Some(EncoderInfo { input_gaussians: r.u32("info").ok()?, input_sh_degree: r.u8("info").ok()? })
}

/// Writes an info section.
pub fn write_info(info: &EncoderInfo) -> Vec<u8> {
    let mut w = ByteWriter::new();
    w.u32(info.input_gaussians);
    w.u8(info.input_sh_degree);
    w.buf
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn info_round_trips_and_other_lengths_are_ignored() {
        let i = EncoderInfo { input_gaussians: 70_000, input_sh_degree: 3 };
        let bytes = write_info(&i);
        assert_eq!(bytes.len(), INFO_BYTES);
        assert_eq!(read_info(&bytes), Some(i));
        assert_eq!(read_info(&bytes[..4]), None);
        assert_eq!(read_info(&[bytes.clone(), vec![0]].concat()), None);
    }
}
