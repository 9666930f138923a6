// The body of every fuzz target, shared by the libFuzzer entry points (fuzz/fuzz_*.cpp) and the
// GoogleTest replay of the crash regression corpus (tests/fuzz_regression_test.cpp), so a
// crasher is replayed exactly as the fuzzer ran it.
//
// Each function takes one fuzz input, writes it (split into its files) into the private scratch
// folder and calls the public loader. It returns when the input loaded and every invariant holds,
// throws specula::Error when the loader refused it (the expected outcome for garbage) and throws
// fuzz::Bug when a loaded result is inconsistent. Any other exception is a bug too.
#pragma once

#include <cstdint>
#include <cstring>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "fuzz_util.h"
#include "specula/error.h"
#include "specula/image.h"
#include "specula/load.h"
#include "specula/ray.h"
#include "specula/scene.h"
#include "specula/svo.h"

namespace specula::fuzz {

/// A scene a loader returned must be complete and consistent.
inline void check_scene(const Scene& scene) {
  try {
    scene.validate();
  } catch (const Error& e) {
    throw Bug(std::string("loader returned an invalid scene: ") + e.what());
  }
  if (scene.triangle_count() == 0) throw Bug("loader returned a scene without triangles");
}

/// OBJ text, optionally followed by kSplit and "m.mtl" (the seeds say "mtllib m.mtl").
inline void one_obj(std::string_view in) {
  const auto parts = split(in, 2);
  const auto obj = put_file("m.obj", parts[0]);
  if (parts.size() > 1) put_file("m.mtl", parts[1]);
  else drop_file("m.mtl");
  check_scene(load_scene(obj.string(), quiet_options()));
}

/// A PLY file, ascii or binary.
inline void one_ply(std::string_view in) {
  check_scene(load_scene(put_file("m.ply", in).string(), quiet_options()));
}

/// .gltf text, optionally followed by kSplit and "b.bin" (an external buffer, "uri": "b.bin").
inline void one_gltf(std::string_view in) {
  const auto parts = split(in, 2);
  const auto gltf = put_file("s.gltf", parts[0]);
  if (parts.size() > 1) put_file("b.bin", parts[1]);
  else drop_file("b.bin");
  check_scene(load_scene(gltf.string(), quiet_options()));
}

/// A binary glTF file: our GLB container checks, then tinygltf.
inline void one_glb(std::string_view in) {
  check_scene(load_scene(put_file("s.glb", in).string(), quiet_options()));
}

/// A JSON scene, then optionally (each after kSplit) "m.obj", "m.ply" and "sky.hdr", which the
/// seeds reference ("file": "m.obj", "image": "sky.hdr"); "builtin" shapes need no file.
inline void one_json_scene(std::string_view in) {
  static const char* const kFiles[] = {"m.obj", "m.ply", "sky.hdr"};
  const auto parts = split(in, 4);
  const auto json = put_file("s.json", parts[0]);
  for (size_t i = 0; i < 3; ++i) {
    if (i + 1 < parts.size()) put_file(kFiles[i], parts[i + 1]);
    else drop_file(kFiles[i]);
  }
  check_scene(load_scene(json.string(), quiet_options()));
}

/// A sky image (load_sky_image -> read_image: our Radiance decoder for .hdr, stb_image for PNG
/// and the other formats it detects, tinyexr for .exr). The file gets the extension its magic number asks for, as a user's file would:
/// OpenEXR "v/1\x01" -> .exr, Radiance "#?" -> .hdr, anything else -> .png.
inline void one_sky_image(std::string_view in) {
  const char* ext = ".png";
  if (in.substr(0, 4) == std::string_view("\x76\x2f\x31\x01", 4)) ext = ".exr";
  else if (in.substr(0, 2) == "#?") ext = ".hdr";
  Sky sky;
  sky.type = SkyType::Image;
  sky.image_path = put_file(std::string("sky") + ext, in).string();
  load_sky_image(sky);
  if (sky.image_width <= 0 || sky.image_height <= 0 ||
      sky.image.size() != static_cast<size_t>(sky.image_width) * static_cast<size_t>(sky.image_height))
    throw Bug("sky image " + std::to_string(sky.image_width) + "x" + std::to_string(sky.image_height) +
              " with " + std::to_string(sky.image.size()) + " pixels");
  for (const Vec3& c : sky.image)
    if (!is_finite(c)) throw Bug("non-finite sky pixel");
}

namespace detail {

inline constexpr size_t kSvoHeader = 80, kSvoChecksumAt = 72;

inline uint64_t svo_checksum(const std::vector<uint8_t>& b) {
  uint64_t h = 14695981039346656037ull;
  for (size_t i = 0; i < b.size(); ++i) {
    if (i >= kSvoChecksumAt && i < kSvoHeader) continue;
    h ^= b[i];
    h *= 1099511628211ull;
  }
  return h;
}

inline void trace_some_rays(const SparseVoxelOctree& svo) {
  const VoxelGrid& g = svo.grid();
  const Vec3 c = g.bounds().center();
  const Vec3 dirs[] = {{1, 0.1f, 0.2f}, {-1, -0.3f, 0.05f}, {0, 1, 0}, {0.3f, -0.2f, -1}, {1, 1, 1}};
  std::vector<Ray> rays;
  for (const Vec3& d : dirs) {
    Ray r;
    r.org = c - d * (2.0f * g.side);  // from outside
    r.dir = d;
    rays.push_back(r);
    r.org = c;  // from inside
    rays.push_back(r);
  }
  std::vector<Hit> hits(rays.size());
  std::vector<Vec3> trans(rays.size());
  svo.intersect(rays, hits);
  svo.transmittance(rays, trans);
  for (const Hit& h : hits)
    if (h.prim != kNoHit) (void)svo.attributes(h.prim);
}

}  // namespace detail

/// A .svo file. A random mutation almost never keeps the FNV-1a checksum right, which would stop
/// the fuzzer at the checksum test, so when the stored checksum (bytes 72..79) is zero the input
/// is sealed with the right one before it is written (the seeds are stored that way); any other
/// value is written as is and exercises the checksum test. A file that loads must be usable:
/// rays through it (cubes and contours, full depth and a coarser level of detail) and writing
/// it back gives the same bytes.
inline void one_svo(std::string_view in) {
  std::vector<uint8_t> bytes(in.begin(), in.end());
  if (bytes.size() >= detail::kSvoHeader) {
    bool zero = true;
    for (size_t i = detail::kSvoChecksumAt; i < detail::kSvoHeader; ++i) zero = zero && bytes[i] == 0;
    if (zero) {
      const uint64_t sum = detail::svo_checksum(bytes);
      for (size_t i = 0; i < 8; ++i) bytes[detail::kSvoChecksumAt + i] = static_cast<uint8_t>(sum >> (8 * i));
    }
  }
  const auto path = put_file("v.svo", {reinterpret_cast<const char*>(bytes.data()), bytes.size()});
  SparseVoxelOctree svo = read_svo(path.string());
  if (svo_to_bytes(svo) != bytes) throw Bug(".svo file read back does not rewrite identically");
  detail::trace_some_rays(svo);
  svo.set_hit_mode(VoxelHitMode::Contours);
  detail::trace_some_rays(svo);
  if (svo.grid().depth > 1) {
    svo.set_lod(svo.grid().depth - 1);
    detail::trace_some_rays(svo);
  }
  (void)svo.to_voxel_set();
}

using TargetFn = void (*)(std::string_view);

/// Every target by name (the name of its executable, corpus and regression folder).
inline const std::map<std::string, TargetFn>& targets() {
  static const std::map<std::string, TargetFn> t{
      {"fuzz_obj", &one_obj},           {"fuzz_ply", &one_ply},   {"fuzz_gltf", &one_gltf},
      {"fuzz_glb", &one_glb},           {"fuzz_json_scene", &one_json_scene},
      {"fuzz_svo", &one_svo},           {"fuzz_sky_image", &one_sky_image}};
  return t;
}

}  // namespace specula::fuzz
