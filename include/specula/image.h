/// \file image.h
/// Image output (PNG through stb_image_write, EXR through tinyexr), HDR sky input, and
/// atomic file writing.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "specula/load.h"  // InputLimits
#include "specula/math.h"
#include "specula/render.h"
#include "specula/scene.h"

namespace specula {

enum class Tonemap : uint8_t { Clamp, Reinhard };

/// Writes \p bytes to \p path atomically: a temporary file in the same folder, fsync, rename.
/// On failure the temporary file is removed and \p path is left as it was. Refuses to
/// overwrite \p protect (e.g. the input file) when given. Throws specula::Error.
void write_file_atomic(const std::string& path, std::span<const uint8_t> bytes,
                       const std::string& protect = {});

/// Throws specula::Error at once when write_file_atomic(\p path) is bound to fail: \p path is a
/// folder, or the folder it would go in does not exist, is not a folder or cannot be written
/// to. Commands call it before long work (loading, building, rendering, voxelizing), so a
/// mistyped output path fails in milliseconds, not after the work is done.
void check_output_path(const std::string& path);

/// For a program that exits on a signal (Ctrl-C): removes the temporary file of every
/// write_file_atomic in progress and makes every write_file_atomic from now on, and every one
/// about to rename its temporary file, wait forever; the caller then exits (_exit). Each output
/// is left either as it was or complete (a rename that already happened), never partial, and no
/// temporary file remains. Not async-signal-safe: call it from a normal thread, e.g. one that
/// waits for the signals with sigwait() (what the specula CLI does).
void stop_atomic_writes();

/// Writes linear RGB as 8-bit sRGB PNG (clamped or Reinhard-tonemapped first).
void write_png(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb,
               Tonemap tonemap = Tonemap::Clamp);
/// Writes linear RGB as a half-float EXR.
void write_exr(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb);
/// Picks PNG or EXR by extension (.png / .exr); throws for anything else.
void write_image(const std::string& path, int width, int height, std::span<const Vec3> linear_rgb,
                 Tonemap tonemap = Tonemap::Clamp);

/// Reads an image into linear RGB (EXR and .hdr are linear; 8-bit formats are sRGB-decoded).
/// Refuses files over limits.max_file_bytes and images whose decoding memory, estimated from
/// the header before decoding, exceeds limits.max_image_bytes (the message gives the estimate).
std::vector<Vec3> read_image(const std::string& path, int& width, int& height,
                             const InputLimits& limits = {});

/// Loads sky.image_path into sky.image (no-op unless sky.type == SkyType::Image).
void load_sky_image(Sky& sky, const InputLimits& limits = {});

/// Writes each AOV of \p film next to \p base_path: "out.png" -> "out.depth.png" etc.
/// (depth and normal as false colour PNG and linear EXR when the base is .exr, prim ids as
/// hashed colours, cost as a heat map). Returns the paths written.
std::vector<std::string> write_aovs(const std::string& base_path, const Film& film);

/// Where write_aovs puts \p aov for \p base_path: "out.png" -> "out.depth.png", "x.exr" ->
/// "x.depth.exr" (so a caller can check every output path before rendering).
std::string aov_path(const std::string& base_path, Aov aov);

}  // namespace specula
