// Integer hashing shared by the integrator (per-pixel sample rotation) and AOV colouring.
#pragma once

#include <cstdint>

namespace specula {

/// Chris Wellons' "lowbias32" integer hash: decorrelates neighbouring indices.
constexpr uint32_t hash_u32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}

}  // namespace specula
