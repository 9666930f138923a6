// Subcommands of the specula CLI. main.cpp parses arguments (CLI11) and calls these; each
// returns the process exit code and throws specula::Error for user errors.
#pragma once

#include <string>

#include "specula/accel.h"
#include "specula/load.h"

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

/// `specula bench trace`: build ms; Mrays/s for primary, shadow, secondary (reflection /
/// refraction) and diffuse bounce rays, one thread and all threads; Embree side by side.
int bench_trace(const BenchTraceOptions& options);

}  // namespace specula::cli
