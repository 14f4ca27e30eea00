// The gateway's binary frames and the map's Gaussian records (docs/viewer.md, docs/protocol.md
// "Map export"): pure functions, no DOM.

// A binary frame: 4-byte ASCII tag, uint32 LE header length H, H bytes of JSON, zero padding to a
// multiple of 8, then the payload.
export function decodeFrame(buffer) {
  const bytes = new Uint8Array(buffer);
  const tag = String.fromCharCode(bytes[0], bytes[1], bytes[2], bytes[3]);
  const length = new DataView(buffer).getUint32(4, true);
  const header = JSON.parse(new TextDecoder().decode(bytes.subarray(8, 8 + length)));
  const start = Math.ceil((8 + length) / 8) * 8;
  return { tag, header, payload: bytes.subarray(start) };
}

// Calls fn(i, x, y, z, sx, sy, sz, qw, qx, qy, qz, r, g, b, a) for each 32-byte record: mean and
// standard deviations (float32, metres, world frame), rotation (int8 x 127, w x y z),
// colour and opacity in [0, 1].
export function forEachRecord(payload, count, fn) {
  const view = new DataView(payload.buffer, payload.byteOffset, payload.byteLength);
  for (let i = 0; i < count; ++i) {
    const o = 32 * i;
    fn(i,
      view.getFloat32(o, true), view.getFloat32(o + 4, true), view.getFloat32(o + 8, true),
      view.getFloat32(o + 12, true), view.getFloat32(o + 16, true), view.getFloat32(o + 20, true),
      view.getInt8(o + 24) / 127, view.getInt8(o + 25) / 127, view.getInt8(o + 26) / 127, view.getInt8(o + 27) / 127,
      payload[o + 28] / 255, payload[o + 29] / 255, payload[o + 30] / 255, payload[o + 31] / 255);
  }
}

// Pinhole intrinsics of a width x height view with vertical field of view fovDeg, pixel centres
// at integers (the server's convention).
export function intrinsicsFor(width, height, fovDeg) {
  const fy = (height / 2) / Math.tan((fovDeg * Math.PI) / 360);
  return { fx: fy, fy, cx: width / 2 - 0.5, cy: height / 2 - 0.5, width, height };
}
