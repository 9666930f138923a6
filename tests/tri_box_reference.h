// Exact reference for triangle / closed box overlap on integer coordinates, shared by
// tri_box_test.cpp and voxelize_test.cpp (see tri_box_test.cpp for the method).
#pragma once

#include <cstdint>
#include <vector>

#include "voxel/tri_box.h"

namespace specula::test {

using i128 = __int128;

struct Con {
  i128 a, b, c;  // a * beta + b * gamma <= c
};

/// True when the closed triangle v meets the closed box: exact 2D feasibility in barycentric
/// coordinates by enumerating the vertices of the feasible polygon (int128, no rounding).
inline bool reference_overlap(const int64_t v[3][3], const specula::voxel::LatticeBox& box) {
  std::vector<Con> cons = {{-1, 0, 0}, {0, -1, 0}, {1, 1, 1}};
  for (int k = 0; k < 3; ++k) {
    const i128 e1 = v[1][k] - v[0][k], e2 = v[2][k] - v[0][k];
    cons.push_back({e1, e2, static_cast<i128>(box.lo[k] + box.size - v[0][k])});
    cons.push_back({-e1, -e2, static_cast<i128>(v[0][k] - box.lo[k])});
  }
  for (const Con& c : cons)
    if (c.a == 0 && c.b == 0 && c.c < 0) return false;
  for (size_t i = 0; i < cons.size(); ++i)
    for (size_t j = i + 1; j < cons.size(); ++j) {
      const Con &p = cons[i], &q = cons[j];
      const i128 d = p.a * q.b - q.a * p.b;
      if (d == 0) continue;
      const i128 xb = p.c * q.b - q.c * p.b;  // beta = xb / d
      const i128 xg = p.a * q.c - q.a * p.c;  // gamma = xg / d
      bool ok = true;
      for (const Con& c : cons) {
        const i128 lhs = c.a * xb + c.b * xg, rhs = c.c * d;
        if (d > 0 ? lhs > rhs : lhs < rhs) {
          ok = false;
          break;
        }
      }
      if (ok) return true;
    }
  return false;
}

}  // namespace specula::test
