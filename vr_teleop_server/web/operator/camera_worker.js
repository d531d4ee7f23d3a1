// Decodes the head camera's JPEG frames off the page's main thread: base64 -> bytes -> ImageBitmap, flipped for
// a WebGL texture. One frame at a time; the page sends the next only when this one is back.
self.onmessage = async (event) => {
  const {data, stamp, seq} = event.data;
  try {
    const bytes = typeof Uint8Array.fromBase64 === "function" ? Uint8Array.fromBase64(data) : decode(data);
    const bitmap = await createImageBitmap(new Blob([bytes], {type: "image/jpeg"}), {imageOrientation: "flipY"});
    self.postMessage({bitmap, stamp, seq}, [bitmap]);
  } catch (err) {
    self.postMessage({error: String(err), stamp, seq});
  }
};

function decode(base64) {
  const text = atob(base64);
  const bytes = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
  return bytes;
}
