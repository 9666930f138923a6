// .svo files: writing (atomic) and validating reader (owner: voxel tracers).
// Format: docs/svo-format.md. Everything is little-endian and written field by field, so the
// bytes depend only on the octree's contents (a rewrite of a file read back is identical).
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <span>
#include <string>
#include <vector>

#include "specula/error.h"
#include "specula/image.h"  // write_file_atomic
#include "specula/svo.h"

namespace specula {

namespace {

constexpr char kMagic[8] = {'S', 'P', 'E', 'C', 'S', 'V', 'O', '\0'};
constexpr uint32_t kVersion = 1;
constexpr size_t kHeaderBytes = 80;
constexpr size_t kChecksumOffset = 72;
constexpr size_t kNodeBytes = 8;
constexpr size_t kAttrBytes = 48;

/// FNV-1a, 64 bit.
struct Fnv1a64 {
  uint64_t h = 14695981039346656037ull;
  void add(std::span<const uint8_t> bytes) {
    for (const uint8_t b : bytes) {
      h ^= b;
      h *= 1099511628211ull;
    }
  }
};

uint64_t checksum(std::span<const uint8_t> file) {
  Fnv1a64 f;
  f.add(file.subspan(0, kChecksumOffset));
  f.add(file.subspan(kHeaderBytes));
  return f.h;
}

class Writer {
 public:
  explicit Writer(std::vector<uint8_t>& out) : out_(out) {}
  void u8(uint8_t v) { out_.push_back(v); }
  void u32(uint32_t v) {
    for (int i = 0; i < 4; ++i) out_.push_back(static_cast<uint8_t>(v >> (8 * i)));
  }
  void u64(uint64_t v) {
    for (int i = 0; i < 8; ++i) out_.push_back(static_cast<uint8_t>(v >> (8 * i)));
  }
  void f32(float v) { u32(std::bit_cast<uint32_t>(v)); }
  void vec3(const Vec3& v) {
    f32(v.x);
    f32(v.y);
    f32(v.z);
  }
  void attrs(const VoxelAttributes& a) {
    vec3(a.normal);
    vec3(a.colour);
    f32(a.reflectivity);
    f32(a.transparency);
    f32(a.ior);
    f32(a.contour_lo);
    f32(a.contour_hi);
    u32(a.material);
  }

 private:
  std::vector<uint8_t>& out_;
};

class Reader {
 public:
  explicit Reader(std::span<const uint8_t> in, size_t at) : in_(in), at_(at) {}
  uint32_t u32() {
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= static_cast<uint32_t>(in_[at_ + i]) << (8 * i);
    at_ += 4;
    return v;
  }
  uint64_t u64() {
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= static_cast<uint64_t>(in_[at_ + i]) << (8 * i);
    at_ += 8;
    return v;
  }
  float f32() { return std::bit_cast<float>(u32()); }
  Vec3 vec3() {
    const float x = f32(), y = f32(), z = f32();
    return {x, y, z};
  }
  VoxelAttributes attrs() {
    VoxelAttributes a;
    a.normal = vec3();
    a.colour = vec3();
    a.reflectivity = f32();
    a.transparency = f32();
    a.ior = f32();
    a.contour_lo = f32();
    a.contour_hi = f32();
    a.material = u32();
    return a;
  }

 private:
  std::span<const uint8_t> in_;
  size_t at_;
};

bool valid_attrs(const VoxelAttributes& a) {
  return is_finite(a.normal) && is_finite(a.colour) && std::isfinite(a.reflectivity) && std::isfinite(a.transparency) &&
         std::isfinite(a.ior) && std::isfinite(a.contour_lo) && std::isfinite(a.contour_hi) && a.contour_lo <= a.contour_hi;
}

}  // namespace

std::vector<uint8_t> svo_to_bytes(const SparseVoxelOctree& svo) {
  const auto nodes = svo.nodes();
  const auto leaves = svo.leaf_attributes();
  const auto inner = svo.inner_attributes();
  std::vector<uint8_t> out;
  out.reserve(kHeaderBytes + nodes.size() * (kNodeBytes + kAttrBytes) + leaves.size() * kAttrBytes);
  Writer w(out);
  for (const char c : kMagic) w.u8(static_cast<uint8_t>(c));
  w.u32(kVersion);
  w.u32(static_cast<uint32_t>(kHeaderBytes));
  w.vec3(svo.grid().origin);
  w.f32(svo.grid().side);
  w.u32(static_cast<uint32_t>(svo.grid().depth));
  w.u32(static_cast<uint32_t>(kAttrBytes));
  w.u64(nodes.size());
  w.u64(leaves.size());
  w.u64(0);  // reserved
  w.u64(0);  // reserved
  w.u64(0);  // checksum, patched below
  for (const SvoNode& n : nodes) {
    w.u32(n.first_child);
    w.u32(n.mask);
  }
  for (const VoxelAttributes& a : leaves) w.attrs(a);
  for (const VoxelAttributes& a : inner) w.attrs(a);
  const uint64_t sum = checksum(out);
  for (int i = 0; i < 8; ++i) out[kChecksumOffset + static_cast<size_t>(i)] = static_cast<uint8_t>(sum >> (8 * i));
  return out;
}

void write_svo(const std::string& path, const SparseVoxelOctree& svo) {
  const std::vector<uint8_t> bytes = svo_to_bytes(svo);
  write_file_atomic(path, bytes);
}

SparseVoxelOctree svo_from_bytes(std::span<const uint8_t> bytes, const std::string& name, const VoxelTracerOptions& options) {
  const auto fail = [&name](const std::string& what) { return file_error(name, what); };
  const size_t size = bytes.size();
  if (size < 8 || std::memcmp(bytes.data(), kMagic, 8) != 0) {
    if (size < 8) throw fail("truncated: " + std::to_string(size) + " bytes, not even a .svo magic number");
    throw fail("not a .svo file (bad magic number)");
  }
  if (size < kHeaderBytes)
    throw fail("truncated: " + std::to_string(size) + " bytes, the header alone needs " + std::to_string(kHeaderBytes));
  Reader h(bytes, 8);
  const uint32_t version = h.u32();
  if (version != kVersion)
    throw fail("unsupported .svo version " + std::to_string(version) + " (this build reads version " +
               std::to_string(kVersion) + ")");
  const uint32_t header_bytes = h.u32();
  if (header_bytes != kHeaderBytes) throw fail("header size " + std::to_string(header_bytes) + ", expected 80");
  VoxelGrid grid;
  grid.origin = h.vec3();
  grid.side = h.f32();
  const uint32_t depth = h.u32();
  const uint32_t attr_bytes = h.u32();
  const uint64_t node_count = h.u64();
  const uint64_t voxel_count = h.u64();
  const uint64_t reserved = h.u64() | h.u64();
  const uint64_t stored_sum = h.u64();
  if (depth > static_cast<uint32_t>(kMaxVoxelDepth))
    throw fail("depth " + std::to_string(depth) + " out of range 0.." + std::to_string(kMaxVoxelDepth));
  grid.depth = static_cast<int>(depth);
  if (!is_finite(grid.origin) || !std::isfinite(grid.side) || !(grid.side > 0.0f) ||
      !std::isfinite(static_cast<float>(grid.resolution()) / grid.side))
    throw fail("grid origin not finite or side not positive and finite");
  if (attr_bytes != kAttrBytes) throw fail("attribute record size " + std::to_string(attr_bytes) + ", expected 48");
  if (reserved != 0) throw fail("reserved header fields are not zero");
  // Sizes before anything is allocated: every count is bounded by the file size first, so the
  // products below cannot overflow.
  const uint64_t payload = size - kHeaderBytes;
  if (node_count > payload / (kNodeBytes + kAttrBytes) || voxel_count > payload / kAttrBytes)
    throw fail("counts (" + std::to_string(node_count) + " nodes, " + std::to_string(voxel_count) +
               " voxels) do not fit in the file's " + std::to_string(size) + " bytes (truncated or corrupt)");
  const uint64_t expected = node_count * (kNodeBytes + kAttrBytes) + voxel_count * kAttrBytes;
  if (expected != payload) {
    if (expected > payload)
      throw fail("truncated: " + std::to_string(size) + " bytes, the counts need " + std::to_string(kHeaderBytes + expected));
    throw fail(std::to_string(payload - expected) + " unexpected bytes after the data");
  }
  if (voxel_count + node_count >= kNoHit) throw fail("too many voxels and nodes for 32-bit prim indices");
  const uint64_t sum = checksum(bytes);
  if (sum != stored_sum) throw fail("checksum mismatch (file corrupt)");

  SparseVoxelOctree svo;
  svo.grid_ = grid;
  svo.mode_ = options.mode;
  svo.set_lod(options.lod);
  svo.nodes_.resize(node_count);
  svo.leaf_attrs_.resize(voxel_count);
  svo.inner_attrs_.resize(node_count);
  Reader rd(bytes, kHeaderBytes);
  for (SvoNode& n : svo.nodes_) {
    n.first_child = rd.u32();
    n.mask = rd.u32();
  }
  for (VoxelAttributes& a : svo.leaf_attrs_) a = rd.attrs();
  for (VoxelAttributes& a : svo.inner_attrs_) a = rd.attrs();
  if (const std::string err = svo.check_structure(); !err.empty()) throw fail("invalid tree: " + err);
  for (size_t i = 0; i < svo.leaf_attrs_.size(); ++i)
    if (!valid_attrs(svo.leaf_attrs_[i]))
      throw fail("voxel " + std::to_string(i) + ": non-finite attribute or contour_lo > contour_hi");
  for (size_t i = 0; i < svo.inner_attrs_.size(); ++i)
    if (svo.nodes_[i].mask != 0 && !valid_attrs(svo.inner_attrs_[i]))
      throw fail("node " + std::to_string(i) + ": non-finite attribute or contour_lo > contour_hi");
  return svo;
}

SparseVoxelOctree read_svo(const std::string& path, const VoxelTracerOptions& options) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw file_error(path, std::string("cannot open: ") + std::strerror(errno));
  const std::streamoff end = in.tellg();
  if (end < 0) throw file_error(path, "cannot determine the file size");
  in.seekg(0);
  std::vector<uint8_t> bytes(static_cast<size_t>(end));
  if (!bytes.empty() && !in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(bytes.size())))
    throw file_error(path, "read failed");
  return svo_from_bytes(bytes, path, options);
}

}  // namespace specula
