// Reads the protobuf messages the server publishes in binary (foxglove.CompressedImage on
// /imaging/{view}/compressed): the wire format's varints and length-delimited fields, by field number
// as in Foxglove's schema (server/proto). Unknown fields are skipped by their wire type, so a newer
// server's additions do not break this reader; a message that does not parse returns null.

function readVarint(bytes, at) {
  let value = 0;
  let scale = 1;
  for (let i = 0; i < 10; ++i) {
    if (at.pos >= bytes.length) throw new Error('truncated varint');
    const b = bytes[at.pos++];
    value += (b & 0x7f) * scale;  // exact up to 2^53: seconds and lengths are far below
    if (b < 0x80) return value;
    scale *= 128;
  }
  throw new Error('varint longer than 10 bytes');
}

// Calls visit(field, wireType, value) per field: a number for varints, a Uint8Array view for
// length-delimited fields.
function readFields(bytes, visit) {
  const at = {pos: 0};
  while (at.pos < bytes.length) {
    const key = readVarint(bytes, at);
    const field = Math.floor(key / 8);
    const wire = key % 8;
    if (wire === 0) {
      visit(field, wire, readVarint(bytes, at));
    } else if (wire === 2) {
      const n = readVarint(bytes, at);
      if (at.pos + n > bytes.length) throw new Error('length beyond the message');
      visit(field, wire, bytes.subarray(at.pos, at.pos + n));
      at.pos += n;
    } else if (wire === 1) {
      at.pos += 8;
    } else if (wire === 5) {
      at.pos += 4;
    } else {
      throw new Error(`unsupported wire type ${wire}`);
    }
    if (at.pos > bytes.length) throw new Error('field beyond the message');
  }
}

const text = new TextDecoder();

// foxglove.CompressedImage → {timestamp: {sec, nsec}, frame_id, data: Uint8Array, format}, or null.
export function decodeCompressedImage(bytes) {
  try {
    const msg = {timestamp: {sec: 0, nsec: 0}, frame_id: '', data: new Uint8Array(0), format: ''};
    readFields(bytes, (field, wire, value) => {
      if (wire !== 2) return;
      if (field === 1) {
        readFields(value, (f, w, v) => {
          if (w !== 0) return;
          if (f === 1) msg.timestamp.sec = v;
          if (f === 2) msg.timestamp.nsec = v;
        });
      } else if (field === 2) {
        msg.data = value;
      } else if (field === 3) {
        msg.format = text.decode(value);
      } else if (field === 4) {
        msg.frame_id = text.decode(value);
      }
    });
    return msg;
  } catch {
    return null;
  }
}
