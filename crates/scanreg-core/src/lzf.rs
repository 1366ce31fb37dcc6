//! LZF (de)compression, as used by PCD `DATA binary_compressed`.
//!
//! The LZF stream is a sequence of chunks, each starting with a control byte `c`:
//! * `c < 32`: a literal run — the next `c + 1` bytes are copied to the output;
//! * otherwise a back-reference: length `L = c >> 5` (if `L == 7`, one more byte is added to
//!   it), offset `((c & 31) << 8) + next byte + 1` back from the end of the output; `L + 2`
//!   bytes are copied one at a time (the source may overlap the bytes being written).
//!
//! Both functions work on untrusted bytes: every index is checked, nothing panics, and the
//! decoder never grows its output beyond the size the caller expects.

use crate::error::{Error, Result};

/// Longest output a single input byte can produce (a 3-byte back-reference yields up to 264
/// bytes); used to refuse absurd declared sizes before allocating.
const MAX_EXPANSION: usize = 88;
const MAX_LITERAL: usize = 32;
const MAX_OFFSET: usize = 1 << 13;
const MAX_MATCH: usize = 7 + 255 + 2;
const HASH_BITS: u32 = 14;

/// Decompress an LZF stream that must expand to exactly `expected_len` bytes.
///
/// Errors (never panics) on a truncated stream, a back-reference before the start of the
/// output, output longer or shorter than `expected_len`, or an `expected_len` that the input
/// cannot possibly produce.
pub fn decompress(input: &[u8], expected_len: usize) -> Result<Vec<u8>> {
    if expected_len > input.len().saturating_mul(MAX_EXPANSION) {
        return Err(Error::invalid(
            "expected_len",
            format!(
                "{expected_len} bytes cannot come from {} compressed bytes",
                input.len()
            ),
        ));
    }
    let mut out: Vec<u8> = Vec::with_capacity(expected_len);
    let mut i = 0usize;
    while i < input.len() {
        let ctrl = usize::from(input[i]);
        i += 1;
        if ctrl < MAX_LITERAL {
            let run = ctrl + 1;
            let end = i
                .checked_add(run)
                .filter(|&e| e <= input.len())
                .ok_or_else(|| truncated(i))?;
            if out.len() + run > expected_len {
                return Err(too_long(expected_len));
            }
            out.extend_from_slice(&input[i..end]);
            i = end;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                len += usize::from(*input.get(i).ok_or_else(|| truncated(i))?);
                i += 1;
            }
            let low = usize::from(*input.get(i).ok_or_else(|| truncated(i))?);
            i += 1;
            let offset = ((ctrl & 0x1f) << 8) + low + 1;
            let len = len + 2;
            if offset > out.len() {
                return Err(Error::invalid(
                    "data",
                    format!(
                        "back-reference {offset} bytes before output position {} (corrupt stream)",
                        out.len()
                    ),
                ));
            }
            if out.len() + len > expected_len {
                return Err(too_long(expected_len));
            }
            let start = out.len() - offset;
            for k in 0..len {
                let b = out[start + k];
                out.push(b);
            }
        }
    }
    if out.len() != expected_len {
        return Err(Error::invalid(
            "data",
            format!(
                "decompressed to {} bytes, expected {expected_len}",
                out.len()
            ),
        ));
    }
    Ok(out)
}

fn truncated(at: usize) -> Error {
    Error::invalid("data", format!("compressed stream truncated at byte {at}"))
}

fn too_long(expected_len: usize) -> Error {
    Error::invalid(
        "data",
        format!("decompresses to more than the expected {expected_len} bytes"),
    )
}

fn hash3(b: &[u8]) -> usize {
    let v = u32::from(b[0]) << 16 | u32::from(b[1]) << 8 | u32::from(b[2]);
    (v.wrapping_mul(2_654_435_761) >> (32 - HASH_BITS)) as usize
}

fn flush_literals(out: &mut Vec<u8>, lit: &[u8]) {
    for chunk in lit.chunks(MAX_LITERAL) {
        // chunk.len() is in 1..=32, so the control byte is in 0..=31.
        out.push((chunk.len() - 1) as u8);
        out.extend_from_slice(chunk);
    }
}

/// Compress `input` into an LZF stream (greedy matching over a hash of 3-byte prefixes).
pub fn compress(input: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(input.len() / 2 + 16);
    let mut table = vec![usize::MAX; 1 << HASH_BITS];
    let mut lit_start = 0usize;
    let mut i = 0usize;
    while i + 2 < input.len() {
        let h = hash3(&input[i..i + 3]);
        let cand = table[h];
        table[h] = i;
        if cand != usize::MAX && i - cand <= MAX_OFFSET && input[cand..cand + 3] == input[i..i + 3]
        {
            let max_len = MAX_MATCH.min(input.len() - i);
            let mut len = 3;
            while len < max_len && input[cand + len] == input[i + len] {
                len += 1;
            }
            flush_literals(&mut out, &input[lit_start..i]);
            let off = i - cand - 1; // < 8192: 13 bits
            let l = len - 2;
            let off_hi = (off >> 8) as u8;
            if l < 7 {
                out.push(((l as u8) << 5) | off_hi);
            } else {
                out.push((7 << 5) | off_hi);
                out.push((l - 7) as u8);
            }
            out.push((off & 0xff) as u8);
            i += len;
            lit_start = i;
        } else {
            i += 1;
        }
    }
    flush_literals(&mut out, &input[lit_start..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(n: usize) -> Vec<u8> {
        // Repetitive with variation, like float columns of a point cloud.
        (0..n)
            .map(|k| ((k * 7 + k / 13) % 23) as u8 ^ ((k / 100) as u8))
            .collect()
    }

    #[test]
    fn round_trip_various_sizes() {
        for n in [0usize, 1, 2, 3, 4, 31, 32, 33, 100, 1000, 70_000] {
            let data = sample(n);
            let packed = compress(&data);
            assert_eq!(decompress(&packed, n).unwrap(), data, "n = {n}");
        }
    }

    #[test]
    fn compresses_repetitive_input() {
        let data = vec![5u8; 10_000];
        let packed = compress(&data);
        assert!(packed.len() < 200, "{}", packed.len());
        assert_eq!(decompress(&packed, data.len()).unwrap(), data);
    }

    #[test]
    fn known_stream() {
        // literal "ab", then a back-reference of length 4 at offset 2 -> "ababab".
        let stream = [1u8, b'a', b'b', (2 << 5), 1];
        assert_eq!(decompress(&stream, 6).unwrap(), b"ababab");
    }

    #[test]
    fn rejects_corrupt_streams() {
        let packed = compress(&sample(5000));
        for cut in 0..packed.len() {
            // Never panics; a strict prefix cannot give the full output.
            assert!(decompress(&packed[..cut], 5000).is_err());
        }
        assert!(decompress(&[(2 << 5), 0], 4).is_err()); // reference before start
        assert!(decompress(&[0, b'x'], 2).is_err()); // too short
        assert!(decompress(&[1, b'x', b'y'], 1).is_err()); // too long
        assert!(decompress(&[0, 0], usize::MAX).is_err()); // absurd size, no allocation
    }

    #[test]
    fn arbitrary_bytes_never_panic() {
        let mut state = 0x1234_5678u32;
        for _ in 0..2000 {
            let len = (state % 64) as usize;
            let bytes: Vec<u8> = (0..len)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 17;
                    state ^= state << 5;
                    state as u8
                })
                .collect();
            let _ = decompress(&bytes, (state % 300) as usize);
        }
    }
}
