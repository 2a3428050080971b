//! The opening of a live connection as the front door passes it on: an HTTP upgrade request
//! from a viewer to the `foxglove` crate's server, and its answer back.
//!
//! The crate's server negotiates only the SDK's names for the protocol (`foxglove.sdk.v1`,
//! `foxglove.sdk.v1.1`) and answers HTTP 400 to a client offering only the name of the
//! protocol's published specification, `foxglove.websocket.v1` (what Lichtblick and Foxglove
//! Studio before the SDK offer). Both names carry the same messages: channel advertisements
//! with inline schemas, `subscribe`/`unsubscribe`, and binary message data. So a request
//! offering only the published name is passed on offering `foxglove.sdk.v1`, and the answer
//! names the protocol the client offered, as RFC 6455 requires.

/// The protocol's name in Foxglove's SDK: inline schemas (what `foxglove.websocket.v1` is).
pub const SDK_V1: &str = "foxglove.sdk.v1";
/// The SDK's newer protocol, whose advertisements refer to a schema table.
pub const SDK_V1_1: &str = "foxglove.sdk.v1.1";
/// The protocol's name in its published specification.
pub const WEBSOCKET_V1: &str = "foxglove.websocket.v1";

/// The header that carries the subprotocols offered and chosen.
const PROTOCOL_HEADER: &str = "sec-websocket-protocol";

/// The index just past the blank line that ends an HTTP head in `bytes`, if it is there.
pub fn head_len(bytes: &[u8]) -> Option<usize> {
    bytes
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map(|i| i + 4)
}

/// An upgrade request as it goes to the crate's server.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Upgrade {
    /// The request's head, perhaps with its subprotocol renamed.
    pub head: Vec<u8>,
    /// The subprotocol to name in the answer instead of the one the crate chose (`None`: the
    /// answer goes back as the crate gives it).
    pub answer_as: Option<&'static str>,
}

/// The request `head` (up to and including its blank line) as the crate's server is to see
/// it: unchanged when it offers a protocol the crate speaks (or none the door knows, which the
/// crate refuses itself), else with `foxglove.websocket.v1` offered as `foxglove.sdk.v1`.
pub fn upgrade_request(head: &[u8]) -> Upgrade {
    let offered: Vec<&[u8]> = header_lines(head)
        .filter_map(protocol_value)
        .flat_map(|v| v.split(|&b| b == b','))
        .map(<[u8]>::trim_ascii)
        .collect();
    let speaks = |name: &str| offered.contains(&name.as_bytes());
    if speaks(SDK_V1) || speaks(SDK_V1_1) || !speaks(WEBSOCKET_V1) {
        return Upgrade {
            head: head.to_vec(),
            answer_as: None,
        };
    }
    Upgrade {
        head: with_protocol(head, SDK_V1),
        answer_as: Some(WEBSOCKET_V1),
    }
}

/// The answer `head` from the crate's server with its chosen subprotocol named `name`.
pub fn answer_as(head: &[u8], name: &str) -> Vec<u8> {
    let switching = head.starts_with(b"HTTP/1.1 101");
    if !switching || !header_lines(head).any(|l| protocol_value(l).is_some()) {
        return head.to_vec();
    }
    with_protocol(head, name)
}

/// `head` with every subprotocol header dropped and one naming `name` added before its blank
/// line.
fn with_protocol(head: &[u8], name: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(head.len() + name.len());
    let mut lines = head.split(|&b| b == b'\n');
    if let Some(first) = lines.next() {
        out.extend_from_slice(first);
        out.push(b'\n');
    }
    for line in header_lines(head) {
        if protocol_value(line).is_none() {
            out.extend_from_slice(line);
            out.extend_from_slice(b"\r\n");
        }
    }
    out.extend_from_slice(format!("Sec-WebSocket-Protocol: {name}\r\n\r\n").as_bytes());
    out
}

/// The header lines of `head` (after its first line, before its blank line), without their
/// line ends.
fn header_lines(head: &[u8]) -> impl Iterator<Item = &[u8]> {
    head.split(|&b| b == b'\n')
        .skip(1)
        .map(|l| l.strip_suffix(b"\r").unwrap_or(l))
        .take_while(|l| !l.is_empty())
}

/// The value of a subprotocol header line, if `line` is one.
fn protocol_value(line: &[u8]) -> Option<&[u8]> {
    let colon = line.iter().position(|&b| b == b':')?;
    let (name, value) = line.split_at(colon);
    name.trim_ascii()
        .eq_ignore_ascii_case(PROTOCOL_HEADER.as_bytes())
        .then(|| &value[1..])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(protocols: &[&str]) -> Vec<u8> {
        let mut r = b"GET / HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\n".to_vec();
        for p in protocols {
            r.extend_from_slice(format!("Sec-WebSocket-Protocol: {p}\r\n").as_bytes());
        }
        r.extend_from_slice(b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n");
        r
    }

    #[test]
    fn a_head_ends_at_its_blank_line() {
        assert_eq!(
            head_len(b"GET / HTTP/1.1\r\nA: b\r\n\r\n\x81\x00"),
            Some(24)
        );
        assert_eq!(head_len(b"GET / HTTP/1.1\r\nA: b\r\n"), None);
    }

    #[test]
    fn the_published_name_alone_is_offered_to_the_crate_as_the_sdks() {
        let up = upgrade_request(&request(&[WEBSOCKET_V1]));
        assert_eq!(up.answer_as, Some(WEBSOCKET_V1));
        let text = String::from_utf8(up.head).expect("ascii");
        assert!(
            text.starts_with("GET / HTTP/1.1\r\nHost: localhost\r\n"),
            "{text}"
        );
        assert!(text.contains("Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"));
        assert!(
            text.ends_with("Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"),
            "{text}"
        );
        assert!(!text.contains(WEBSOCKET_V1));
    }

    #[test]
    fn a_request_the_crate_answers_itself_passes_unchanged() {
        for offered in [
            vec![SDK_V1],
            vec!["foxglove.sdk.v1.1, foxglove.websocket.v1"],
            vec![WEBSOCKET_V1, SDK_V1],
            vec!["chat"],
            vec![],
        ] {
            let r = request(&offered);
            assert_eq!(
                upgrade_request(&r),
                Upgrade {
                    head: r.clone(),
                    answer_as: None
                },
                "{offered:?}"
            );
        }
    }

    #[test]
    fn names_in_one_header_and_any_case_are_read() {
        let r = b"GET / HTTP/1.1\r\nsec-websocket-PROTOCOL:  x.y ,foxglove.websocket.v1\r\n\r\n";
        assert_eq!(upgrade_request(r).answer_as, Some(WEBSOCKET_V1));
    }

    #[test]
    fn the_answer_names_the_protocol_the_client_offered() {
        let head = b"HTTP/1.1 101 Switching Protocols\r\nConnection: Upgrade\r\n\
                     sec-websocket-protocol: foxglove.sdk.v1\r\nsec-websocket-accept: abc\r\n\r\n";
        let text = String::from_utf8(answer_as(head, WEBSOCKET_V1)).expect("ascii");
        assert_eq!(
            text,
            "HTTP/1.1 101 Switching Protocols\r\nConnection: Upgrade\r\n\
             sec-websocket-accept: abc\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n"
        );
        // A refusal is passed on as it is.
        let refused = b"HTTP/1.1 400 Bad Request\r\ncontent-length: 3\r\n\r\n";
        assert_eq!(answer_as(refused, WEBSOCKET_V1), refused.to_vec());
    }
}
