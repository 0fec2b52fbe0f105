"""Write a modified copy of an RGL tensor file: the rgb field replaced (same shape and dtype)."""
import struct, numpy as np
from neumat.io.rgl import DTYPES

def field_offsets(raw):
    pos = 12 + 2
    (count,) = struct.unpack_from('<I', raw, pos); pos += 4
    out = {}
    for _ in range(count):
        (nl,) = struct.unpack_from('<H', raw, pos); pos += 2
        name = raw[pos:pos + nl].decode(); pos += nl
        (ndim,) = struct.unpack_from('<H', raw, pos); pos += 2
        (code,) = struct.unpack_from('<B', raw, pos); pos += 1
        (off,) = struct.unpack_from('<Q', raw, pos); pos += 8
        shape = struct.unpack_from(f'<{ndim}Q', raw, pos) if ndim else (); pos += 8 * ndim
        out[name] = (off, shape, DTYPES[code])
    return out

def write_modified(src, dst, fields: dict):
    raw = bytearray(open(src, 'rb').read())
    offs = field_offsets(bytes(raw))
    for name, arr in fields.items():
        off, shape, dt = offs[name]
        a = np.ascontiguousarray(arr, dtype=dt)
        assert a.shape == tuple(shape), (a.shape, shape)
        raw[off:off + a.nbytes] = a.tobytes()
    open(dst, 'wb').write(bytes(raw))
