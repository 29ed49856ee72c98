//! Samples as the bytes of a CDR message, header included: rustdds hands a reader the payload
//! and its representation id, and takes a writer's payload without them. The bytes are read
//! and written by the project's own CDR code (`stillpoint_datasets::mcap::cdr`), the same that
//! reads ROS 2 recordings, so a live sample and a recorded one are decoded alike.

use rustdds::RepresentationIdentifier;
use rustdds::bytes::Bytes;
use rustdds::no_key::{DeserializerAdapter, SerializerAdapter};

/// One serialised message: CDR's 4-byte encapsulation header, then the payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CdrMessage(pub Vec<u8>);

/// The adapter between rustdds and [`CdrMessage`].
pub struct RawCdr;

/// A sample whose payload was not plain CDR.
#[derive(Debug, thiserror::Error)]
#[error("representation {0:?} is not plain CDR")]
pub struct NotCdr(pub [u8; 2]);

impl DeserializerAdapter<CdrMessage> for RawCdr {
    type Error = NotCdr;
    type Decoded = CdrMessage;

    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &[
            RepresentationIdentifier::CDR_LE,
            RepresentationIdentifier::CDR_BE,
            RepresentationIdentifier::CDR2_LE,
            RepresentationIdentifier::CDR2_BE,
        ]
    }

    fn transform_decoded(decoded: CdrMessage) -> CdrMessage {
        decoded
    }
}

impl rustdds::no_key::DefaultDecoder<CdrMessage> for RawCdr {
    type Decoder = Prefix;
    const DECODER: Prefix = Prefix;
}

/// Puts the representation id back in front of the payload (options zero).
#[derive(Clone, Copy)]
pub struct Prefix;

impl<'de> rustdds::no_key::Decode<'de, CdrMessage> for Prefix {
    type Error = NotCdr;

    fn decode_bytes(
        self,
        input_bytes: &'de [u8],
        encoding: RepresentationIdentifier,
    ) -> Result<CdrMessage, NotCdr> {
        let id = encoding.to_bytes();
        let mut v = Vec::with_capacity(input_bytes.len() + 4);
        v.extend_from_slice(&[id[0], id[1], 0, 0]);
        v.extend_from_slice(input_bytes);
        Ok(CdrMessage(v))
    }
}

/// A message written with the wrong header for this adapter.
#[derive(Debug, thiserror::Error)]
#[error("a message to send starts with {0:02x?}, not little-endian CDR's 00 01")]
pub struct NotLittleEndian(pub Vec<u8>);

impl SerializerAdapter<CdrMessage> for RawCdr {
    type Error = NotLittleEndian;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    fn to_bytes(value: &CdrMessage) -> Result<Bytes, NotLittleEndian> {
        match value.0.get(..4) {
            Some([0, 1, _, _]) => Ok(Bytes::copy_from_slice(&value.0[4..])),
            other => Err(NotLittleEndian(other.unwrap_or(&value.0).to_vec())),
        }
    }
}
