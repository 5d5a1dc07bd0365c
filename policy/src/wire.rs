//! msgpack encoding of the remote-policy protocol (docs/remote-protocol.md).
//!
//! Arrays use the openpi convention `{"__ndarray__": true, "data": <bytes>,
//! "dtype": "<f4", "shape": [...]}` with the batch as the first dimension. Map
//! keys may be msgpack str or bin (openpi's packer writes bin keys).

use rmpv::Value;

/// Version of docs/remote-protocol.md this evaluator speaks.
pub const PROTOCOL_VERSION: u64 = 1;

/// Nesting limit when decoding untrusted frames (the protocol needs 3).
const MAX_DEPTH: usize = 16;

pub fn encode(v: &Value) -> Vec<u8> {
    let mut out = Vec::new();
    // Writing into a Vec cannot fail.
    let _ = rmpv::encode::write_value(&mut out, v);
    out
}

/// Decode one complete frame; trailing bytes are an error.
pub fn decode(bytes: &[u8]) -> Result<Value, String> {
    // rmpv reads the reserved marker 0xc1 as nil; for a frame it means garbage.
    if bytes.first() == Some(&0xc1) {
        return Err("not valid msgpack (starts with the reserved byte 0xc1)".into());
    }
    let mut rd = bytes;
    let v = rmpv::decode::read_value_with_max_depth(&mut rd, MAX_DEPTH)
        .map_err(|e| format!("not valid msgpack ({e})"))?;
    if !rd.is_empty() {
        return Err(format!(
            "{} bytes of trailing data after the msgpack value",
            rd.len()
        ));
    }
    if !matches!(v, Value::Map(_)) {
        return Err(format!(
            "expected a msgpack map with a `type` field, got {v}"
        ));
    }
    Ok(v)
}

pub fn map(entries: Vec<(&str, Value)>) -> Value {
    Value::Map(
        entries
            .into_iter()
            .map(|(k, v)| (Value::from(k), v))
            .collect(),
    )
}

/// Look up `key` in a msgpack map (str or bin key).
pub fn get<'a>(v: &'a Value, key: &str) -> Option<&'a Value> {
    let Value::Map(m) = v else { return None };
    m.iter().find_map(|(k, val)| {
        let matches = match k {
            Value::String(s) => s.as_str() == Some(key),
            Value::Binary(b) => b.as_slice() == key.as_bytes(),
            _ => false,
        };
        matches.then_some(val)
    })
}

pub fn get_str<'a>(v: &'a Value, key: &str) -> Result<&'a str, String> {
    match get(v, key) {
        Some(Value::String(s)) => s
            .as_str()
            .ok_or_else(|| format!("field `{key}` is not valid UTF-8")),
        Some(Value::Binary(b)) => {
            std::str::from_utf8(b).map_err(|_| format!("field `{key}` is not valid UTF-8"))
        }
        Some(other) => Err(format!("field `{key}` should be a string, got {other}")),
        None => Err(format!("missing field `{key}`")),
    }
}

pub fn get_u64(v: &Value, key: &str) -> Result<u64, String> {
    match get(v, key) {
        Some(x) => x
            .as_u64()
            .ok_or_else(|| format!("field `{key}` should be a non-negative integer, got {x}")),
        None => Err(format!("missing field `{key}`")),
    }
}

pub fn u64_array(xs: &[u64]) -> Value {
    Value::Array(xs.iter().map(|&x| Value::from(x)).collect())
}

/// `{"__ndarray__": true, "data": <little-endian f32 bytes>, "dtype": "<f4", "shape": [...]}`.
pub fn encode_f32(shape: &[usize], data: &[f32]) -> Value {
    let mut bytes = Vec::with_capacity(data.len() * 4);
    for x in data {
        bytes.extend_from_slice(&x.to_le_bytes());
    }
    map(vec![
        ("__ndarray__", Value::Boolean(true)),
        ("data", Value::Binary(bytes)),
        ("dtype", Value::from("<f4")),
        (
            "shape",
            Value::Array(shape.iter().map(|&d| Value::from(d as u64)).collect()),
        ),
    ])
}

/// Decode an ndarray as float32. `<f4` is taken as is, `<f8` is converted (numpy
/// defaults to float64 and a server forgetting `.astype(np.float32)` should not
/// fail for that alone); other dtypes are refused.
pub fn decode_f32(v: &Value) -> Result<(Vec<usize>, Vec<f32>), String> {
    match get(v, "__ndarray__") {
        Some(Value::Boolean(true)) => {}
        _ => return Err(
            "expected an array encoded as {\"__ndarray__\": true, \"data\", \"dtype\", \"shape\"}"
                .into(),
        ),
    }
    let dtype = get_str(v, "dtype")?;
    let shape: Vec<usize> = match get(v, "shape") {
        Some(Value::Array(a)) => a
            .iter()
            .map(|d| {
                d.as_u64()
                    .and_then(|d| usize::try_from(d).ok())
                    .ok_or_else(|| format!("array shape entry {d} is not a non-negative integer"))
            })
            .collect::<Result<_, _>>()?,
        _ => return Err("array field `shape` should be a list of integers".into()),
    };
    let data = match get(v, "data") {
        Some(Value::Binary(b)) => b.as_slice(),
        _ => return Err("array field `data` should be bytes".into()),
    };
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or("array shape overflows")?;
    let item = match dtype {
        "<f4" | "float32" => 4,
        "<f8" | "float64" => 8,
        other => {
            return Err(format!(
                "array dtype `{other}` is not supported; send little-endian float32 (`<f4`)"
            ))
        }
    };
    if count.checked_mul(item) != Some(data.len()) {
        return Err(format!(
            "array of shape {shape:?} and dtype {dtype} needs {} bytes but `data` has {}",
            count.saturating_mul(item),
            data.len()
        ));
    }
    let out = if item == 4 {
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    } else {
        data.chunks_exact(8)
            .map(|c| {
                let mut b = [0u8; 8];
                b.copy_from_slice(c);
                f64::from_le_bytes(b) as f32
            })
            .collect()
    };
    Ok((shape, out))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn array_roundtrip_and_bin_keys() {
        let v = encode_f32(&[2, 1, 2], &[1.0, -2.5, f32::NAN, 4.0]);
        let back = decode(&encode(&v)).unwrap();
        let (shape, data) = decode_f32(&back).unwrap();
        assert_eq!(shape, [2, 1, 2]);
        assert_eq!(data[0], 1.0);
        assert!(data[2].is_nan());
        // openpi-style bin keys and float64 data.
        let bin = Value::Map(vec![
            (Value::Binary(b"__ndarray__".to_vec()), Value::Boolean(true)),
            (
                Value::Binary(b"data".to_vec()),
                Value::Binary(0.5f64.to_le_bytes().to_vec()),
            ),
            (Value::Binary(b"dtype".to_vec()), Value::from("<f8")),
            (
                Value::Binary(b"shape".to_vec()),
                Value::Array(vec![1.into()]),
            ),
        ]);
        assert_eq!(decode_f32(&bin).unwrap(), (vec![1], vec![0.5]));
    }

    #[test]
    fn bad_arrays_are_described() {
        let mut v = encode_f32(&[3], &[1.0, 2.0]);
        assert!(decode_f32(&v)
            .unwrap_err()
            .contains("needs 12 bytes but `data` has 8"));
        if let Value::Map(m) = &mut v {
            m[2].1 = Value::from("<i8");
        }
        assert!(decode_f32(&v)
            .unwrap_err()
            .contains("`<i8` is not supported"));
        assert!(decode(&[0xc1]).is_err());
        assert!(decode(&[0x80, 0x02]).unwrap_err().contains("trailing"));
        assert!(decode(&[0x01])
            .unwrap_err()
            .contains("expected a msgpack map"));
        // Deep nesting is refused instead of overflowing the stack.
        let deep = vec![0x91u8; 10_000];
        assert!(decode(&deep).is_err());
    }
}
