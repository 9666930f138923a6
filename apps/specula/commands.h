// Subcommands of the specula CLI. main.cpp parses arguments (CLI11) and calls these; each
// returns the process exit code and throws specula::Error for user errors.
#pragma once

#include <string>

#include "specula/accel.h"
#include "specula/load.h"
#include "specula/render.h"

namespace specula::cli {

struct BenchTraceOptions {
  std::string scene = "pool";  ///< SCENE spec (built-in, json, gltf, mesh)
  std::string mesh;            ///< --mesh FILE: bench a bare mesh instead (overrides scene)
  int width = 640, height = 480;
  int threads = 0;             ///< 0 = all hardware threads for the "all threads" column
  int repeat = 3;              ///< passes per measurement; the median is printed
  BvhOptions bvh;
  LoadOptions load;
  bool embree = true;          ///< compare against Embree when compiled in
};

struct RenderOptions {
  std::string scene;
  std::string output = "specula.png";
  std::string accel = "bvh";
  std::string aovs;              ///< comma-separated AOV names
  std::string tonemap = "clamp";
  int frames = 1;
  specula::RenderOptions render;
  BvhOptions bvh;
  LoadOptions load;
};

struct TraceOptions {
  std::string scene;
  std::string rays;              ///< ray file, "-" = stdin
  std::string accel = "bvh";
  bool stats = false;
  int repeat = 1;
  int threads = 1;
  BvhOptions bvh;
  LoadOptions load;
};

struct InfoOptions {
  std::string scene;
  LoadOptions load;
};

/// `specula render`: load, build, render, write the image (+ AOVs), print timings.
int render(const RenderOptions& options);
/// `specula trace`: trace a ray file, print "t prim" or "miss" per ray.
int trace(const TraceOptions& options);
/// `specula info`: describe a scene.
int info(const InfoOptions& options);

/// `specula bench trace`: build ms; Mrays/s for primary, shadow, secondary (reflection /
/// refraction) and diffuse bounce rays, one thread and all threads; Embree side by side.
int bench_trace(const BenchTraceOptions& options);

}  // namespace specula::cli
