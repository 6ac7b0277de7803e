// SPDX-License-Identifier: Apache-2.0
// A ray prepared once for all the box and triangle tests of one traversal, in double
// precision (float inputs convert exactly, so coordinates up to FLT_MAX neither overflow
// nor round before the tests).
#pragma once

#include <cmath>
#include <utility>

namespace clastrace::engine::geometry {

struct PreparedRay {
    double o[3], d[3];
    double inv[3];      // 1 / d; never read for a zero component (slab.h tests those apart)
    int kx, ky, kz;     // the watertight test's dimension permutation: kz the largest |d|
    double sx, sy, sz;  // its shear
    double tmin, tmax;  // the query interval (closed, as Vulkan's)
};

inline PreparedRay prepare_ray(const double o[3], const double d[3], double tmin, double tmax) {
    PreparedRay r;
    for (int a = 0; a < 3; ++a) {
        r.o[a] = o[a];
        r.d[a] = d[a];
        r.inv[a] = 1.0 / d[a];
    }
    int kz = 0;
    if (std::fabs(d[1]) > std::fabs(d[kz])) kz = 1;
    if (std::fabs(d[2]) > std::fabs(d[kz])) kz = 2;
    int kx = (kz + 1) % 3, ky = (kx + 1) % 3;
    // Swapping x and y when the major component is negative keeps the triangles' winding.
    if (d[kz] < 0.0) std::swap(kx, ky);
    r.kx = kx;
    r.ky = ky;
    r.kz = kz;
    r.sx = d[kx] / d[kz];
    r.sy = d[ky] / d[kz];
    r.sz = 1.0 / d[kz];
    r.tmin = tmin;
    r.tmax = tmax;
    return r;
}

}  // namespace clastrace::engine::geometry
