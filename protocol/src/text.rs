//! Fixed-size text fields: names and messages travel as NUL-padded UTF-8 byte arrays, because a
//! shared-memory type holds no pointers.

use crate::ProtocolError;

/// Writes `name` into a NUL-padded array, refusing names that do not fit (one byte stays NUL so
/// a reader always finds the end) or that contain a NUL.
pub fn encode_name<const N: usize>(
    field: &'static str,
    name: &str,
) -> Result<[u8; N], ProtocolError> {
    let bytes = name.as_bytes();
    if bytes.len() >= N {
        return Err(ProtocolError::NameTooLong {
            field,
            name: name.to_owned(),
            max_bytes: N - 1,
        });
    }
    if bytes.contains(&0) {
        return Err(ProtocolError::InvalidName {
            field,
            name: name.to_owned(),
            reason: "contains a NUL byte",
        });
    }
    let mut out = [0u8; N];
    out[..bytes.len()].copy_from_slice(bytes);
    Ok(out)
}

/// Writes `text` into a NUL-padded array. Text too long is cut after the last whole word that
/// leaves room for "…", which tells the reader that more was said (for free-form messages, where
/// losing the tail beats losing the message).
pub fn encode_truncated<const N: usize>(text: &str) -> [u8; N] {
    let mut out = [0u8; N];
    // One byte stays NUL, so a reader always finds the end.
    let room = N.saturating_sub(1);
    if text.len() <= room {
        out[..text.len()].copy_from_slice(text.as_bytes());
        return out;
    }
    const MORE: &str = "…";
    let Some(mut end) = room.checked_sub(MORE.len()) else {
        return out;
    };
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    // Back to the end of the last whole word, unless that loses more than a quarter of the room
    // (a long path or number is cut where it stands). A cut right after a word keeps it.
    let after_a_word = text.as_bytes()[end] == b' ';
    if let Some(space) = text[..end].rfind(' ').filter(|_| !after_a_word) {
        if space >= end - end / 4 {
            end = space;
        }
    }
    end = text[..end].trim_end_matches([' ', ',', ';', ':']).len();
    out[..end].copy_from_slice(&text.as_bytes()[..end]);
    out[end..end + MORE.len()].copy_from_slice(MORE.as_bytes());
    out
}

/// Reads a NUL-padded field: the bytes before the first NUL, replacing invalid UTF-8.
pub fn decode(bytes: &[u8]) -> std::borrow::Cow<'_, str> {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_are_nul_terminated() {
        let a: [u8; 8] = encode_name("camera", "kinect").unwrap();
        assert_eq!(decode(&a), "kinect");
        assert_eq!(a[6..], [0, 0]);
    }

    #[test]
    fn names_that_do_not_fit_are_refused() {
        assert!(encode_name::<8>("camera", "1234567").is_ok());
        let e = encode_name::<8>("camera", "12345678").unwrap_err();
        assert!(e.to_string().contains("at most 7 bytes"), "{e}");
        // The name is quoted as Rust writes a string, once: a NUL shows as `\0`.
        let e = encode_name::<8>("camera", "a\0b").unwrap_err();
        assert_eq!(e.to_string(), r#"camera name "a\0b" contains a NUL byte"#);
    }

    #[test]
    fn messages_that_fit_are_kept_whole() {
        let m: [u8; 7] = encode_truncated("ééé");
        assert_eq!(decode(&m), "ééé");
    }

    #[test]
    fn messages_are_cut_at_character_boundaries_and_marked() {
        // 4 bytes of text room before "…": "é" and half of the next.
        let m: [u8; 8] = encode_truncated("éééé");
        assert_eq!(decode(&m), "éé…");
        let m: [u8; 7] = encode_truncated("éééé");
        assert_eq!(decode(&m), "é…");
        let m: [u8; 3] = encode_truncated("éééé");
        assert_eq!(decode(&m), "");
    }

    #[test]
    fn long_messages_are_cut_after_a_whole_word() {
        let text = "object 7 cannot be loaded: the mesh has no faces, and a model needs them";
        let m: [u8; 48] = encode_truncated(text);
        assert_eq!(decode(&m), "object 7 cannot be loaded: the mesh has no…");
        // A cut that falls right after a word keeps it.
        let m: [u8; 27] = encode_truncated("aaaaaaaaaaaaaaaaaaaa bb cc dd");
        assert_eq!(decode(&m), "aaaaaaaaaaaaaaaaaaaa bb…");
        // A word longer than a quarter of the room is cut where it stands.
        let m: [u8; 24] = encode_truncated("path /a/very/long/folder/name/of/models");
        assert_eq!(decode(&m), "path /a/very/long/fo…");
    }
}
