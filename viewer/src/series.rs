//! Plain numbers over time, as ROS 2's `std_msgs/msg/Float64MultiArray` in CDR: the one numeric
//! message Rerun's MCAP importer turns into its scalars (a time series), and one Foxglove
//! plots (`/tes/decision/latency_us.data[0]`). Encoded by the `cdr` crate.

use foxglove::{Encode, Schema};
use serde::Serialize;

/// The message definition, as ROS 2 bags carry it (`ros2msg`).
const DEFINITION: &str = "std_msgs/MultiArrayLayout layout
float64[] data
================================================================================
MSG: std_msgs/MultiArrayLayout
MultiArrayDimension[] dim
uint32 data_offset
================================================================================
MSG: std_msgs/MultiArrayDimension
string label
uint32 size
uint32 stride
";

#[derive(Debug, Clone, Default, PartialEq, Serialize)]
struct Dimension {
    label: String,
    size: u32,
    stride: u32,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize)]
struct Layout {
    dim: Vec<Dimension>,
    data_offset: u32,
}

/// One value of a series.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Sample {
    layout: Layout,
    data: Vec<f64>,
}

impl Sample {
    /// The value `v`.
    pub fn of(v: f64) -> Self {
        Self {
            layout: Layout::default(),
            data: vec![v],
        }
    }
}

/// Why a sample could not be encoded (only a writer that refuses bytes).
#[derive(Debug, thiserror::Error)]
#[error("cannot encode a sample: {0}")]
pub struct SampleError(String);

impl Encode for Sample {
    type Error = SampleError;

    fn get_schema() -> Option<Schema> {
        Some(Schema::new(
            "std_msgs/msg/Float64MultiArray",
            "ros2msg",
            DEFINITION.as_bytes().to_vec(),
        ))
    }

    fn get_message_encoding() -> String {
        "cdr".to_owned()
    }

    fn encode(&self, buf: &mut impl foxglove::bytes::BufMut) -> Result<(), Self::Error> {
        let bytes = cdr::serialize::<_, _, cdr::CdrLe>(self, cdr::Infinite)
            .map_err(|e| SampleError(e.to_string()))?;
        buf.put_slice(&bytes);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sample_is_little_endian_cdr_with_an_empty_layout_and_one_value() {
        let mut bytes = Vec::new();
        Sample::of(12.5).encode(&mut bytes).expect("encodes");
        // Encapsulation (CDR, little endian); no dimensions; offset 0; one value, aligned to 8
        // from the end of the encapsulation.
        let mut expect = vec![0, 1, 0, 0];
        expect.extend(0u32.to_le_bytes());
        expect.extend(0u32.to_le_bytes());
        expect.extend(1u32.to_le_bytes());
        expect.extend([0; 4]);
        expect.extend(12.5f64.to_le_bytes());
        assert_eq!(bytes, expect);
    }
}
