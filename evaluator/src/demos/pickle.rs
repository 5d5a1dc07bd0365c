//! A minimal writer of Python pickles (protocol 3) for the demonstration
//! files: nested dicts of strings, lists of strings, and float64 arrays.
//!
//! Arrays are written with numpy's public functions only
//! (`numpy.array(numpy.reshape(numpy.frombuffer(raw, "<f8"), shape))`), not
//! with numpy's private `_reconstruct` (renamed between numpy 1 and 2), so the
//! files load with `pickle.load` under either. The result is an ordinary,
//! writable, C-ordered float64 array, as the reference's recorded episodes are.
//! Opcodes: <https://github.com/python/cpython/blob/3.11/Lib/pickletools.py>.

/// A value the writer can emit.
pub enum Py {
    Str(String),
    List(Vec<Py>),
    /// Keys in the order given (dicts keep insertion order since Python 3.7).
    Dict(Vec<(String, Py)>),
    /// Row-major float64 array of the given shape.
    Array {
        shape: Vec<usize>,
        data: Vec<f64>,
    },
}

/// The bytes of `pickle.dumps(value, protocol=3)`-compatible data.
pub fn dumps(value: &Py) -> Vec<u8> {
    let mut out = vec![0x80, 3]; // PROTO 3
    write(&mut out, value);
    out.push(b'.'); // STOP
    out
}

fn write_str(out: &mut Vec<u8>, s: &str) {
    out.push(b'X'); // BINUNICODE
    out.extend((s.len() as u32).to_le_bytes());
    out.extend(s.as_bytes());
}

fn write_global(out: &mut Vec<u8>, module: &str, name: &str) {
    out.push(b'c'); // GLOBAL
    out.extend(module.as_bytes());
    out.push(b'\n');
    out.extend(name.as_bytes());
    out.push(b'\n');
}

fn write_int(out: &mut Vec<u8>, v: usize) {
    out.push(b'J'); // BININT (signed 32-bit)
    out.extend((i32::try_from(v).expect("array dimension fits i32")).to_le_bytes());
}

fn write(out: &mut Vec<u8>, value: &Py) {
    match value {
        Py::Str(s) => write_str(out, s),
        Py::List(items) => {
            out.push(b']'); // EMPTY_LIST
            if !items.is_empty() {
                out.push(b'('); // MARK
                for it in items {
                    write(out, it);
                }
                out.push(b'e'); // APPENDS
            }
        }
        Py::Dict(entries) => {
            out.push(b'}'); // EMPTY_DICT
            if !entries.is_empty() {
                out.push(b'(');
                for (k, v) in entries {
                    write_str(out, k);
                    write(out, v);
                }
                out.push(b'u'); // SETITEMS
            }
        }
        Py::Array { shape, data } => {
            assert_eq!(shape.iter().product::<usize>(), data.len(), "array shape");
            write_global(out, "numpy", "array");
            write_global(out, "numpy", "reshape");
            write_global(out, "numpy", "frombuffer");
            out.push(b'B'); // BINBYTES
            out.extend(((data.len() * 8) as u32).to_le_bytes());
            for v in data {
                out.extend(v.to_le_bytes());
            }
            write_str(out, "<f8");
            out.push(0x86); // TUPLE2 (raw, dtype)
            out.push(b'R'); // REDUCE: frombuffer(raw, "<f8")
            out.push(b'(');
            for &d in shape {
                write_int(out, d);
            }
            out.push(b't'); // TUPLE: the shape
            out.push(0x86); // TUPLE2 (flat, shape)
            out.push(b'R'); // REDUCE: reshape(flat, shape)
            out.push(0x85); // TUPLE1
            out.push(b'R'); // REDUCE: array(view), a writable copy
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strings_and_lists_have_the_standard_encoding() {
        // pickle.dumps(["a"], protocol=3) minus memo opcodes (which are optional).
        let b = dumps(&Py::List(vec![Py::Str("a".into())]));
        assert_eq!(b, b"\x80\x03](X\x01\x00\x00\x00ae.");
        assert_eq!(dumps(&Py::Dict(vec![])), b"\x80\x03}.");
    }
}
