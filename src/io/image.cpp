// PNG / EXR output, image input and sky loading (owner: render).
// stb_image(_write) and tinyexr come as prebuilt libraries (Debian's libstb.so and
// libtinyexr.so), so only their declarations are included here.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wsign-compare"
#include <stb_image.h>
#include <stb_image_write.h>
#include <tinyexr.h>
#pragma GCC diagnostic pop

#include "io/image_util.h"
#include "specula/error.h"
#include "specula/image.h"

namespace specula {

namespace fs = std::filesystem;

namespace {

std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

void check_size(const std::string& path, int width, int height, size_t pixels) {
  if (width <= 0 || height <= 0)
    throw file_error(path, "invalid image size " + std::to_string(width) + "x" + std::to_string(height));
  if (pixels != static_cast<size_t>(width) * static_cast<size_t>(height))
    throw file_error(path, "pixel count " + std::to_string(pixels) + " does not match " +
                               std::to_string(width) + "x" + std::to_string(height));
}

void append_bytes(void* context, void* data, int size) {
  auto* out = static_cast<std::vector<uint8_t>*>(context);
  const auto* p = static_cast<const uint8_t*>(data);
  out->insert(out->end(), p, p + size);
}

}  // namespace

float linear_to_srgb(float c) {
  if (!(c > 0.0f)) return 0.0f;  // also maps NaN to 0
  if (c >= 1.0f) return 1.0f;
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
}

float srgb_to_linear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

std::vector<uint8_t> to_srgb8(std::span<const Vec3> linear_rgb, Tonemap tonemap) {
  std::vector<uint8_t> px(linear_rgb.size() * 3);
  for (size_t i = 0; i < linear_rgb.size(); ++i) {
    for (int c = 0; c < 3; ++c) {
      float v = linear_rgb[i][c];
      if (std::isnan(v)) v = 0.0f;
      if (tonemap == Tonemap::Reinhard && v > 0.0f) v = std::isinf(v) ? 1.0f : v / (1.0f + v);
      px[3 * i + static_cast<size_t>(c)] = static_cast<uint8_t>(std::lround(linear_to_srgb(v) * 255.0f));
    }
  }
  return px;
}

std::vector<uint8_t> encode_png_srgb8(int width, int height, std::span<const uint8_t> rgb8) {
  std::vector<uint8_t> bytes;
  const int ok = stbi_write_png_to_func(append_bytes, &bytes, width, height, 3, rgb8.data(), width * 3);
  if (!ok) throw Error("PNG encoding failed");
  return bytes;
}

void write_png(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb,
               Tonemap tonemap) {
  check_size(path, width, height, linear_rgb.size());
  const std::vector<uint8_t> px = to_srgb8(linear_rgb, tonemap);
  write_file_atomic(path, encode_png_srgb8(width, height, px));
}

std::vector<uint8_t> encode_exr(int width, int height, std::span<const Vec3> linear_rgb) {
  // Planar channels in the B, G, R order most EXR readers expect; float in, half stored.
  const size_t n = linear_rgb.size();
  std::vector<float> planes[3];
  for (auto& p : planes) p.resize(n);
  for (size_t i = 0; i < n; ++i) {
    planes[0][i] = linear_rgb[i].z;
    planes[1][i] = linear_rgb[i].y;
    planes[2][i] = linear_rgb[i].x;
  }
  unsigned char* image_ptrs[3] = {reinterpret_cast<unsigned char*>(planes[0].data()),
                                  reinterpret_cast<unsigned char*>(planes[1].data()),
                                  reinterpret_cast<unsigned char*>(planes[2].data())};
  EXRImage image;
  InitEXRImage(&image);
  image.num_channels = 3;
  image.images = image_ptrs;
  image.width = width;
  image.height = height;

  EXRHeader header;
  InitEXRHeader(&header);
  EXRChannelInfo channels[3];
  std::memset(channels, 0, sizeof channels);
  std::strcpy(channels[0].name, "B");
  std::strcpy(channels[1].name, "G");
  std::strcpy(channels[2].name, "R");
  int pixel_types[3] = {TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT};
  int requested[3] = {TINYEXR_PIXELTYPE_HALF, TINYEXR_PIXELTYPE_HALF, TINYEXR_PIXELTYPE_HALF};
  header.num_channels = 3;
  header.channels = channels;
  header.pixel_types = pixel_types;
  header.requested_pixel_types = requested;
  header.compression_type = TINYEXR_COMPRESSIONTYPE_ZIP;

  unsigned char* mem = nullptr;
  const char* err = nullptr;
  size_t size = SaveEXRImageToMemory(&image, &header, &mem, &err);
  if (size == 0) {  // retry uncompressed in case this tinyexr build lacks zlib
    if (err) FreeEXRErrorMessage(err);
    err = nullptr;
    header.compression_type = TINYEXR_COMPRESSIONTYPE_NONE;
    size = SaveEXRImageToMemory(&image, &header, &mem, &err);
  }
  if (size == 0) {
    const std::string msg = err ? err : "unknown error";
    if (err) FreeEXRErrorMessage(err);
    throw Error("EXR encoding failed: " + msg);
  }
  std::vector<uint8_t> bytes(mem, mem + size);
  std::free(mem);
  return bytes;
}

void write_exr(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb) {
  check_size(path, width, height, linear_rgb.size());
  std::vector<uint8_t> bytes;
  try {
    bytes = encode_exr(width, height, linear_rgb);
  } catch (const Error& e) {
    throw file_error(path, e.what());
  }
  write_file_atomic(path, bytes);
}

void write_image(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb,
                 Tonemap tonemap) {
  const std::string ext = lower_extension(path);
  if (ext == ".png") return write_png(path, width, height, linear_rgb, tonemap);
  if (ext == ".exr") return write_exr(path, width, height, linear_rgb);
  throw file_error(path, "unsupported image format '" + ext + "' (use .png or .exr)");
}

namespace {

/// Decoding memory budget of one image (the decoder's buffers plus our linear RGB copy,
/// InputLimits::max_image_bytes, 1 GiB by default: e.g. 8192 x 4096 RGB): a 570-byte EXR
/// claiming huge tiles made tinyexr allocate 3 GB (found by fuzz_sky_image). The estimate is
/// computed in 64 bits from the header, before decoding, and printed on refusal.
void check_decode_budget(const std::string& path, const InputLimits& limits, uint64_t bytes, const std::string& what) {
  if (bytes > limits.max_image_bytes)
    throw file_error(path, what + " needs about " + format_bytes(bytes) + " to decode, over the limit of " +
                               format_bytes(limits.max_image_bytes, true) + " (--max-image-memory raises it)");
}

/// Reads a whole image file after checking its size against limits.max_file_bytes and the
/// decoder's own ceiling \p hard_max (stb_image takes an int length).
template <class Bytes>
Bytes read_image_file(const std::string& path, const InputLimits& limits, uintmax_t hard_max, const char* decoder) {
  std::error_code ec;
  const uintmax_t size = fs::file_size(path, ec);
  if (ec) throw file_error(path, "cannot read file size: " + ec.message());
  if (size > limits.max_file_bytes)
    throw file_error(path, file_size_refusal(size, limits));
  if (size > hard_max)
    throw file_error(path, std::string(decoder) + " reads files of at most " + format_bytes(hard_max));
  std::ifstream in(path, std::ios::binary);
  Bytes bytes(static_cast<size_t>(size), 0);
  if (!in || (size > 0 && !in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(size))))
    throw file_error(path, "cannot read image: read error");
  return bytes;
}

/// Radiance RGBE (.hdr) decoding, our own instead of stb_image's: stb_image 2.27 (Debian 12)
/// loops forever on an RLE scanline cut short by the end of the file (it reads zero-length runs
/// past the end, CVE-2021-42715; found by fuzz_sky_image), and allocates and zero-fills
/// whatever size a truncated file's header claims. Same conventions as stb_image: first line
/// "#?RADIANCE" or "#?RGBE", FORMAT=32-bit_rle_rgbe, resolution "-Y H +X W" (top to bottom);
/// each scanline flat (4 bytes a pixel) or new-style RLE (8 <= W < 32768: 2 2 W>>8 W&255, then
/// each channel as runs); value = byte * 2^(E - 136), black when E = 0. Every count is
/// checked against the bytes left, before anything is allocated.
bool is_radiance(const std::string& data) {
  return data.rfind("#?RADIANCE\n", 0) == 0 || data.rfind("#?RGBE\n", 0) == 0;
}

std::vector<Vec3> decode_radiance(const std::string& path, const InputLimits& limits, const std::string& data, int& width,
                                  int& height) {
  const auto fail = [&path](const std::string& what) { return file_error(path, "cannot read Radiance HDR: " + what); };
  size_t pos = 0;
  const auto next_line = [&](std::string& line) {
    const size_t end = data.find('\n', pos);
    if (end == std::string::npos) throw fail("header has no end (truncated)");
    line.assign(data, pos, std::min<size_t>(end - pos, 256));
    pos = end + 1;
  };
  std::string line;
  next_line(line);  // the magic, checked by is_radiance()
  bool rgbe = false;
  for (;;) {
    next_line(line);
    if (line.empty()) break;
    if (line.rfind("FORMAT=", 0) == 0) {
      if (line != "FORMAT=32-bit_rle_rgbe") throw fail("unsupported " + line.substr(0, 40) + " (only 32-bit_rle_rgbe)");
      rgbe = true;
    }
  }
  if (!rgbe) throw fail("no FORMAT=32-bit_rle_rgbe line");
  next_line(line);
  int64_t h = 0, w = 0;
  {
    const char* b = line.data();
    const char* e = b + line.size();
    if (line.rfind("-Y ", 0) != 0) throw fail("unsupported resolution line '" + line.substr(0, 40) + "' (only -Y H +X W)");
    auto r = std::from_chars(b + 3, e, h);
    const char* p = r.ptr;
    if (r.ec != std::errc() || e - p < 4 || std::string_view(p, 4) != " +X ") throw fail("bad resolution line '" + line.substr(0, 40) + "'");
    r = std::from_chars(p + 4, e, w);
    if (r.ec != std::errc() || r.ptr != e) throw fail("bad resolution line '" + line.substr(0, 40) + "'");
  }
  if (w < 1 || h < 1 || w > (int64_t{1} << 24) || h > (int64_t{1} << 24))
    throw fail("invalid size " + std::to_string(w) + "x" + std::to_string(h));
  const bool rle = w >= 8 && w < 32768;
  // The least bytes a scanline can take: 4 a pixel flat, or a 4-byte header and 2 bytes per run
  // of at most 127 values per channel.
  const uint64_t min_line = rle ? std::min<uint64_t>(4 * static_cast<uint64_t>(w), 4 + 8 * ((static_cast<uint64_t>(w) + 126) / 127))
                                : 4 * static_cast<uint64_t>(w);
  const uint64_t left = data.size() - pos;
  if (static_cast<uint64_t>(h) * min_line > left)
    throw fail("truncated: " + std::to_string(w) + "x" + std::to_string(h) + " pixels need at least " +
               std::to_string(static_cast<uint64_t>(h) * min_line) + " bytes of pixel data, the file has " + std::to_string(left));
  const auto byte = [&]() -> uint8_t {
    if (pos >= data.size()) throw fail("truncated pixel data");
    return static_cast<uint8_t>(data[pos++]);
  };
  const auto convert = [](const uint8_t* q) {
    if (q[3] == 0) return Vec3{};
    const float f = std::ldexp(1.0f, static_cast<int>(q[3]) - 136);
    return Vec3{static_cast<float>(q[0]) * f, static_cast<float>(q[1]) * f, static_cast<float>(q[2]) * f};
  };
  check_decode_budget(path, limits, static_cast<uint64_t>(w) * static_cast<uint64_t>(h) * sizeof(Vec3),
                      std::to_string(w) + "x" + std::to_string(h) + " Radiance HDR");
  const size_t W = static_cast<size_t>(w);
  std::vector<Vec3> out(W * static_cast<size_t>(h));
  std::vector<uint8_t> scan(4 * W);
  for (size_t j = 0; j < static_cast<size_t>(h); ++j) {
    const bool rle_line = rle && data.size() - pos >= 4 && data[pos] == 2 && data[pos + 1] == 2 &&
                          (static_cast<uint8_t>(data[pos + 2]) & 0x80) == 0;
    if (rle_line) {
      pos += 2;
      const size_t hi = byte(), lo = byte();
      const size_t len = hi << 8 | lo;
      if (len != W) throw fail("scanline " + std::to_string(j) + ": RLE length " + std::to_string(len) + ", width " + std::to_string(W));
      for (size_t k = 0; k < 4; ++k) {
        for (size_t i = 0; i < W;) {
          size_t count = byte();
          if (count > 128) {
            count -= 128;
            if (count > W - i) throw fail("scanline " + std::to_string(j) + ": RLE run past the end of the line");
            const uint8_t v = byte();
            for (size_t z = 0; z < count; ++z) scan[4 * i++ + k] = v;
          } else {
            if (count == 0 || count > W - i) throw fail("scanline " + std::to_string(j) + ": bad RLE count " + std::to_string(count));
            for (size_t z = 0; z < count; ++z) scan[4 * i++ + k] = byte();
          }
        }
      }
    } else {
      if (data.size() - pos < 4 * W) throw fail("truncated pixel data");
      std::memcpy(scan.data(), data.data() + pos, 4 * W);
      pos += 4 * W;
    }
    for (size_t i = 0; i < W; ++i) out[j * W + i] = convert(&scan[4 * i]);
  }
  width = static_cast<int>(w);
  height = static_cast<int>(h);
  return out;
}

bool is_png(const std::string& data) { return data.compare(0, 8, "\x89PNG\r\n\x1a\n", 8) == 0; }
bool is_jpeg(const std::string& data) { return data.compare(0, 3, "\xff\xd8\xff", 3) == 0; }

/// A JPEG too small for the size it declares is refused before stb_image 2.27 decodes it:
/// every 8x8 block of a component costs at least one bit (its DC code), so w x h pixels need
/// w h / 512 bytes; a quarter of that is required (stb_image reads zeros past the end of the
/// data and would return a silently wrong image).
void check_jpeg_size(const std::string& path, const std::string& data, int width, int height) {
  const uint64_t need = static_cast<uint64_t>(width) * static_cast<uint64_t>(height) / 2048;
  if (data.size() < need)
    throw file_error(path, "cannot read JPEG: a " + std::to_string(width) + "x" + std::to_string(height) +
                               " image needs at least " + std::to_string(need) + " bytes, the file has " +
                               std::to_string(data.size()) + " (truncated or corrupt)");
}

/// Walks a JPEG's marker segments before stb_image 2.27 sees them and refuses a Huffman table
/// (DHT) whose 16 code-length counts add up to more than 256 symbols: stb_image writes one
/// size byte per symbol into a 257-byte array before it checks anything (out-of-bounds write,
/// found by fuzz_sky_image), and a JPEG table holds at most 256 symbols. A DHT segment whose
/// tables run past its own length, or any segment running past the end of the file, is refused
/// as corrupt. Progressive JPEGs define tables between scans, so the entropy-coded data after
/// each SOS is skipped (FF 00 is a stuffed byte, FF D0-D7 a restart marker; any other marker
/// ends the scan) and, like stb_image, bytes between segments that are not a marker are skipped;
/// the walk goes on to EOI. The file must end its first scan with that EOI (FF D9, which
/// entropy-coded data cannot contain): stb_image reads zeros past the end of a truncated file
/// and returns a silently wrong image. \p data must be a JPEG (is_jpeg).
void check_jpeg_segments(const std::string& path, const std::string& data) {
  const auto byte = [&](size_t i) { return static_cast<uint8_t>(data[i]); };
  const auto fail = [&](size_t at, const std::string& what) {
    return file_error(path, "cannot read JPEG: byte " + std::to_string(at) + ": " + what);
  };
  const auto truncated = [&] {
    return file_error(path, "cannot read JPEG: no end-of-image marker after the image data (truncated)");
  };
  bool scanned = false;  // an SOS segment was seen
  size_t at = 2;         // after SOI
  while (at < data.size()) {
    if (byte(at) != 0xff) {  // padding between segments: stb_image skips it too
      ++at;
      continue;
    }
    while (at < data.size() && byte(at) == 0xff) ++at;  // fill bytes
    if (at >= data.size()) break;
    const uint8_t marker = byte(at);
    const size_t start = at - 1;
    ++at;
    if (marker == 0xd9) {  // EOI: the end, after the image data or (no SOS) instead of it
      if (!scanned) throw truncated();
      return;
    }
    if (marker == 0x01 || (marker >= 0xd0 && marker <= 0xd8)) continue;  // no length field
    if (data.size() - at < 2) throw fail(start, "truncated marker segment");
    const size_t len = static_cast<size_t>(byte(at)) << 8 | byte(at + 1);
    if (len < 2 || len > data.size() - at)
      throw fail(start, "marker segment of " + std::to_string(len) + " bytes, the file has " +
                            std::to_string(data.size() - at) + " left (truncated or corrupt)");
    const size_t end = at + len;
    if (marker == 0xc4) {
      for (size_t t = at + 2; t < end;) {
        if (end - t < 17) throw fail(t, "truncated Huffman table");
        size_t symbols = 0;
        for (size_t i = 1; i <= 16; ++i) symbols += byte(t + i);
        if (symbols > 256)
          throw fail(t, "Huffman table of " + std::to_string(symbols) + " symbols (at most 256)");
        if (symbols > end - t - 17) throw fail(t, "Huffman table runs past its segment");
        t += 17 + symbols;
      }
    }
    at = end;
    if (marker == 0xda) {  // entropy-coded data up to the next marker that is not RSTn
      scanned = true;
      while (at + 1 < data.size()) {
        if (byte(at) == 0xff) {
          const uint8_t next = byte(at + 1);
          if (next != 0x00 && next != 0xff && !(next >= 0xd0 && next <= 0xd7)) break;
        }
        ++at;
      }
      if (at + 1 >= data.size()) break;  // no end of scan
    }
  }
  throw truncated();  // the data ended before EOI
}

/// \p bytes with anything outside printable ASCII shown as '?' (chunk types in messages).
std::string printable(std::string bytes) {
  for (char& c : bytes)
    if (c < 0x20 || c > 0x7e) c = '?';
  return bytes;
}

/// Walks a PNG's chunks, up to IEND, before stb_image 2.27 sees them:
/// * a chunk whose length field claims more bytes than the file has left is refused: stb_image
///   grows its IDAT buffer to the claimed length (rounded up to a power of two) before it
///   reads, so a 142-byte PNG claiming a 1.7 GB IDAT made it allocate 2 GiB (found by
///   fuzz_sky_image);
/// * zero-length IDAT chunks are removed: stb_image copies a zero-length first IDAT with memcpy
///   from a null buffer (undefined behaviour, found by fuzz_sky_image; they are legal PNG and
///   carry no image data).
/// \p data must be a PNG (is_png); bytes after IEND are kept as they are (stb_image ignores them).
void check_png_chunks(const std::string& path, std::string& data) {
  std::string out = data.substr(0, 8);
  size_t at = 8;
  while (at < data.size()) {
    if (data.size() - at < 12)
      throw file_error(path, "cannot read PNG: byte " + std::to_string(at) + ": truncated chunk header");
    uint32_t len = 0;
    for (size_t i = 0; i < 4; ++i) len = len << 8 | static_cast<uint8_t>(data[at + i]);
    const std::string type = data.substr(at + 4, 4);
    if (len > data.size() - at - 12)
      throw file_error(path, "cannot read PNG: byte " + std::to_string(at) + ": chunk '" + printable(type) +
                                 "' claims " + std::to_string(len) + " bytes, the file has " +
                                 std::to_string(data.size() - at - 12) + " left (truncated or corrupt)");
    const size_t chunk = 12 + static_cast<size_t>(len);
    if (!(len == 0 && type == "IDAT")) out.append(data, at, chunk);
    at += chunk;
    if (type == "IEND") break;
  }
  out.append(data, at, std::string::npos);
  data.swap(out);
}

/// Owns a parsed EXR header and a decoded image; frees what tinyexr allocated.
struct ExrState {
  EXRHeader header;
  EXRImage image;
  bool have_header = false, have_image = false;
  ExrState() {
    InitEXRHeader(&header);
    InitEXRImage(&image);
  }
  ~ExrState() {
    if (have_image) FreeEXRImage(&image);
    if (have_header) FreeEXRHeader(&header);
  }
  ExrState(const ExrState&) = delete;
  ExrState& operator=(const ExrState&) = delete;
};

std::string take_exr_error(const char* err) {
  std::string msg = err ? err : "unknown error";
  if (err) FreeEXRErrorMessage(err);
  while (!msg.empty() && (msg.back() == '\n' || msg.back() == ' ')) msg.pop_back();
  return msg;
}

/// tinyexr 1.0.1 trusts the size of a "tiles" attribute: it reads 9 bytes from a shorter value
/// (std::out_of_range from vector::at, or a heap over-read; found by fuzz_sky_image). So the
/// header's attribute list (name, type, int32 size, value; an empty name ends it) is walked
/// first: names and types terminated, sizes inside the file, "tiles" exactly 9 bytes.
void check_exr_attributes(const std::string& path, const std::vector<unsigned char>& bytes) {
  const auto fail = [&path](const std::string& what) { return file_error(path, "cannot read EXR: " + what); };
  size_t at = 8;  // after the magic number and the version field
  const auto cstring = [&](std::string& out) {
    const size_t stop = std::min(bytes.size(), at + 256);
    size_t end = at;
    while (end < stop && bytes[end] != 0) ++end;
    if (end >= stop) throw fail("byte " + std::to_string(at) + ": header attribute name or type not terminated");
    out.assign(reinterpret_cast<const char*>(bytes.data()) + at, end - at);
    at = end + 1;
  };
  std::string name, type;
  for (;;) {
    if (at >= bytes.size()) throw fail("truncated header");
    if (bytes[at] == 0) return;  // end of the header
    const size_t start = at;
    cstring(name);
    cstring(type);
    if (bytes.size() - at < 4) throw fail("truncated header");
    uint32_t u = 0;
    for (int i = 3; i >= 0; --i) u = u << 8 | bytes[at + static_cast<size_t>(i)];
    at += 4;
    const int32_t size = static_cast<int32_t>(u);
    if (size < 0 || static_cast<size_t>(size) > bytes.size() - at)
      throw fail("byte " + std::to_string(start) + ": attribute '" + name + "' claims " + std::to_string(size) +
                 " bytes, more than the file holds");
    if (name == "tiles" && size != 9)
      throw fail("byte " + std::to_string(start) + ": attribute 'tiles' has " + std::to_string(size) + " bytes, expected 9");
    at += static_cast<size_t>(size);
  }
}

/// Where a single-part EXR's chunk offset table starts (after the magic number, the version
/// and the header), and how many 8-byte offsets the file has room for from there.
struct ExrOffsetTable {
  uint64_t start, room;
};
ExrOffsetTable exr_offset_table(const EXRHeader& h, const std::vector<unsigned char>& bytes) {
  const uint64_t start = 8 + uint64_t{h.header_len};
  return {start, start > bytes.size() ? 0 : (bytes.size() - start) / 8};
}

/// tinyexr 1.0.1 multiplies a chunk's tile coordinates by the tile size in int without checks
/// (signed overflow for hostile coordinates, found by fuzz_sky_image), so every tile's
/// coordinates are checked here first: the offset table must point inside the file at tiles
/// with 0 <= x < tiles across, 0 <= y < tiles down, level 0. Only single-level tiled images
/// are accepted (sky images have no use for mipmaps).
void check_exr_tiles(const std::string& path, const EXRHeader& h, const std::vector<unsigned char>& bytes) {
  const auto fail = [&path](const std::string& what) { return file_error(path, "cannot read EXR: " + what); };
  if (h.tile_level_mode != TINYEXR_TILE_ONE_LEVEL) throw fail("mipmapped or ripmapped tiled images are not supported");
  const int64_t w = int64_t{h.data_window.max_x} - h.data_window.min_x + 1;
  const int64_t ht = int64_t{h.data_window.max_y} - h.data_window.min_y + 1;
  if (w <= 0 || ht <= 0 || h.tile_size_x <= 0 || h.tile_size_y <= 0) throw fail("invalid data window or tile size");
  const uint64_t nx = static_cast<uint64_t>((w + h.tile_size_x - 1) / h.tile_size_x);
  const uint64_t ny = static_cast<uint64_t>((ht + h.tile_size_y - 1) / h.tile_size_y);
  const ExrOffsetTable table = exr_offset_table(h, bytes);
  if (nx > table.room || nx * ny > table.room) throw fail("truncated tile offset table");
  const uint64_t first = table.start + 8 * nx * ny;
  const auto u64 = [&bytes](uint64_t at) {
    uint64_t v = 0;
    for (int i = 7; i >= 0; --i) v = v << 8 | bytes[static_cast<size_t>(at) + static_cast<size_t>(i)];
    return v;
  };
  const auto i32 = [&bytes](uint64_t at) {
    uint32_t v = 0;
    for (int i = 3; i >= 0; --i) v = v << 8 | bytes[static_cast<size_t>(at) + static_cast<size_t>(i)];
    return static_cast<int32_t>(v);
  };
  for (uint64_t k = 0; k < nx * ny; ++k) {
    const uint64_t off = u64(table.start + 8 * k);
    if (off < first || bytes.size() < 20 || off > bytes.size() - 20)
      throw fail("tile " + std::to_string(k) + ": offset " + std::to_string(off) + " outside the pixel data");
    const int64_t x = i32(off), y = i32(off + 4), lx = i32(off + 8), ly = i32(off + 12);
    if (x < 0 || static_cast<uint64_t>(x) >= nx || y < 0 || static_cast<uint64_t>(y) >= ny || lx != 0 || ly != 0)
      throw fail("tile " + std::to_string(k) + ": coordinates (" + std::to_string(x) + ", " + std::to_string(y) + ", level " +
                 std::to_string(lx) + ", " + std::to_string(ly) + ") outside the " + std::to_string(nx) + "x" +
                 std::to_string(ny) + " tiles");
  }
}

/// OpenEXR through tinyexr's memory API rather than LoadEXR(): tinyexr 1.0.1's LoadEXR leaks
/// the channel buffers of an image whose pixel data fails to decode (its FreeEXRImage frees
/// image.num_channels buffers, a count it sets only on success), so the count is set before
/// decoding here. Single-part scanline or tiled images, half / float / uint channels, like LoadEXR.
std::vector<Vec3> read_exr(const std::string& path, const InputLimits& limits, int& width, int& height) {
  const auto bytes = read_image_file<std::vector<unsigned char>>(path, limits, uintmax_t{1} << 32, "tinyexr");
  EXRVersion version;
  if (ParseEXRVersionFromMemory(&version, bytes.data(), bytes.size()) != TINYEXR_SUCCESS)
    throw file_error(path, "cannot read EXR: not an OpenEXR file (bad magic number or version)");
  if (version.multipart || version.non_image)
    throw file_error(path, "cannot read EXR: multi-part and deep images are not supported");
  check_exr_attributes(path, bytes);
  ExrState st;
  const char* err = nullptr;
  if (ParseEXRHeaderFromMemory(&st.header, &version, bytes.data(), bytes.size(), &err) != TINYEXR_SUCCESS) {
    FreeEXRHeader(&st.header);  // may hold a partly parsed header
    InitEXRHeader(&st.header);
    throw file_error(path, "cannot read EXR: " + take_exr_error(err));
  }
  st.have_header = true;
  EXRHeader& h = st.header;
  for (int c = 0; c < h.num_channels; ++c)
    if (h.pixel_types[c] == TINYEXR_PIXELTYPE_HALF) h.requested_pixel_types[c] = TINYEXR_PIXELTYPE_FLOAT;
  if (h.tiled) check_exr_tiles(path, h, bytes);
  // tinyexr 1.0.1 sizes a scanline image's offset table by its "chunkCount" attribute when
  // there is one, unchecked: 8 bytes per claimed chunk (a 527-byte file claiming 1.8 billion
  // made it allocate 14 GB; found by fuzz_sky_image). The table must fit in the file.
  if (!h.tiled && h.chunk_count > 0) {
    if (static_cast<uint64_t>(h.chunk_count) > exr_offset_table(h, bytes).room)
      throw file_error(path, "cannot read EXR: chunkCount " + std::to_string(h.chunk_count) +
                                 " claims more chunk offsets than the file holds (" + std::to_string(bytes.size()) +
                                 " bytes)");
  }
  {
    const int64_t dw = int64_t{h.data_window.max_x} - h.data_window.min_x + 1;
    const int64_t dh = int64_t{h.data_window.max_y} - h.data_window.min_y + 1;
    if (dw <= 0 || dh <= 0 || dw > (int64_t{1} << 24) || dh > (int64_t{1} << 24) || h.num_channels <= 0 || h.num_channels > 1024)
      throw file_error(path, "cannot read EXR: invalid data window " + std::to_string(dw) + "x" + std::to_string(dh) +
                                 " or channel count " + std::to_string(h.num_channels));
    // tinyexr holds every channel as 4-byte values (whole tiles when tiled), then our RGB copy.
    uint64_t stored = static_cast<uint64_t>(dw) * static_cast<uint64_t>(dh);
    if (h.tiled) {
      const uint64_t tx = static_cast<uint64_t>(h.tile_size_x), ty = static_cast<uint64_t>(h.tile_size_y);
      stored = ((static_cast<uint64_t>(dw) + tx - 1) / tx) * ((static_cast<uint64_t>(dh) + ty - 1) / ty);
      stored = tx * ty > (uint64_t{1} << 40) / std::max<uint64_t>(stored, 1) ? uint64_t{1} << 40 : stored * tx * ty;
    }
    check_decode_budget(path, limits, std::min<uint64_t>(stored, uint64_t{1} << 40) * 4 * static_cast<uint64_t>(h.num_channels) +
                                  static_cast<uint64_t>(dw) * static_cast<uint64_t>(dh) * sizeof(Vec3),
                        std::to_string(dw) + "x" + std::to_string(dh) + " EXR with " + std::to_string(h.num_channels) + " channels");
  }
  st.image.num_channels = h.num_channels;  // see above: lets a failed decode free its buffers
  if (LoadEXRImageFromMemory(&st.image, &h, bytes.data(), bytes.size(), &err) != TINYEXR_SUCCESS)
    throw file_error(path, "cannot read EXR: " + take_exr_error(err));  // tinyexr freed the image
  st.have_image = true;
  EXRImage& img = st.image;

  // Channels as LoadEXR picks them: a single channel is grey; otherwise R, G and B among the
  // first four channels, layer prefixes ("diffuse.R") ignored.
  int idx[3] = {-1, -1, -1};
  if (h.num_channels == 1) {
    idx[0] = idx[1] = idx[2] = 0;
  } else {
    for (int c = 0; c < std::min(h.num_channels, 4); ++c) {
      std::string name = h.channels[c].name;
      if (const size_t dot = name.find_last_of('.'); dot != std::string::npos) name.erase(0, dot + 1);
      if (name == "R") idx[0] = c;
      else if (name == "G") idx[1] = c;
      else if (name == "B") idx[2] = c;
    }
    if (idx[0] < 0 || idx[1] < 0 || idx[2] < 0)
      throw file_error(path, "cannot read EXR: no R, G and B channels among the first four (and not a single channel)");
  }
  width = img.width;
  height = img.height;
  if (width <= 0 || height <= 0 || img.num_channels != h.num_channels)
    throw file_error(path, "cannot read EXR: invalid image size " + std::to_string(width) + "x" + std::to_string(height));
  const auto value = [&](unsigned char* const* planes, int c, size_t i) -> float {
    if (h.pixel_types[c] == TINYEXR_PIXELTYPE_UINT) return static_cast<float>(reinterpret_cast<const uint32_t*>(planes[c])[i]);
    return reinterpret_cast<const float*>(planes[c])[i];
  };
  std::vector<Vec3> out(static_cast<size_t>(width) * static_cast<size_t>(height));
  if (!h.tiled) {
    if (img.images == nullptr) throw file_error(path, "cannot read EXR: no pixel data");
    for (size_t i = 0; i < out.size(); ++i)
      out[i] = {value(img.images, idx[0], i), value(img.images, idx[1], i), value(img.images, idx[2], i)};
    return out;
  }
  // Tiles of level 0: tile_size_x * tile_size_y values per channel, placed at offset * tile size.
  const int64_t tw = h.tile_size_x, th = h.tile_size_y;
  if (tw <= 0 || th <= 0 || (img.num_tiles > 0 && img.tiles == nullptr))
    throw file_error(path, "cannot read EXR: invalid tiles");
  for (int t = 0; t < img.num_tiles; ++t) {
    const EXRTile& tile = img.tiles[t];
    if (tile.images == nullptr || tile.level_x != 0 || tile.level_y != 0) continue;
    for (int64_t j = 0; j < th; ++j) {
      const int64_t y = int64_t{tile.offset_y} * th + j;
      if (y < 0 || y >= height) continue;
      for (int64_t i = 0; i < tw; ++i) {
        const int64_t x = int64_t{tile.offset_x} * tw + i;
        if (x < 0 || x >= width) continue;
        const size_t src = static_cast<size_t>(j * tw + i);
        out[static_cast<size_t>(y * width + x)] = {value(tile.images, idx[0], src), value(tile.images, idx[1], src),
                                                   value(tile.images, idx[2], src)};
      }
    }
  }
  return out;
}

}  // namespace

std::vector<Vec3> read_image(const std::string& path, int& width, int& height, const InputLimits& limits) {
  if (!fs::exists(path)) throw file_error(path, "no such file");
  const std::string ext = lower_extension(path);
  std::vector<Vec3> out;
  if (ext == ".exr") return read_exr(path, limits, width, height);
  std::string bytes = read_image_file<std::string>(path, limits, (uintmax_t{1} << 31) - 1, "stb_image");
  if (is_radiance(bytes)) return decode_radiance(path, limits, bytes, width, height);  // already linear
  // stb_image also sniffs TGA (which has no magic number: any bytes can pass for one), BMP, PSD,
  // GIF, PIC and PNM; only PNG and JPEG are handed to it.
  const bool png = is_png(bytes), jpeg = is_jpeg(bytes);
  if (!png && !jpeg)
    throw file_error(path, "cannot read image: not a PNG, JPEG, Radiance (.hdr) or OpenEXR (.exr) file");
  if (png) check_png_chunks(path, bytes);
  if (jpeg) check_jpeg_segments(path, bytes);
  int channels = 0;
  if (stbi_info_from_memory(reinterpret_cast<const stbi_uc*>(bytes.data()), static_cast<int>(bytes.size()), &width, &height,
                            &channels) &&
      width > 0 && height > 0) {
    if (jpeg) check_jpeg_size(path, bytes, width, height);
    check_decode_budget(path, limits, static_cast<uint64_t>(width) * static_cast<uint64_t>(height) * (4 + sizeof(Vec3)),
                        std::to_string(width) + "x" + std::to_string(height) + " image");
  }
  unsigned char* data = stbi_load_from_memory(reinterpret_cast<const stbi_uc*>(bytes.data()), static_cast<int>(bytes.size()),
                                              &width, &height, &channels, 3);
  if (!data) throw file_error(path, std::string("cannot read image: ") + stbi_failure_reason());
  float lut[256];
  for (int i = 0; i < 256; ++i) lut[i] = srgb_to_linear(static_cast<float>(i) / 255.0f);
  const size_t n = static_cast<size_t>(width) * static_cast<size_t>(height);
  out.resize(n);
  for (size_t i = 0; i < n; ++i) out[i] = {lut[data[3 * i]], lut[data[3 * i + 1]], lut[data[3 * i + 2]]};
  stbi_image_free(data);
  return out;
}

void load_sky_image(Sky& sky, const InputLimits& limits) {
  if (sky.type != SkyType::Image) return;
  if (sky.image_path.empty()) throw Error("sky: type is image but no image path is given");
  int w = 0, h = 0;
  std::vector<Vec3> img = read_image(sky.image_path, w, h, limits);
  for (Vec3& c : img)
    if (!is_finite(c)) c = Vec3{};
  sky.image = std::move(img);
  sky.image_width = w;
  sky.image_height = h;
}

}  // namespace specula
