// SPDX-License-Identifier: Apache-2.0
// A ray prepared once for all the box and triangle tests of one traversal, in double
// precision (float inputs convert exactly, so coordinates up to FLT_MAX neither overflow
// nor round before the tests), and for TraversalMode::kFloat32 in float as well: the
// tests then run on the float copies (geometry/float32.h).
#pragma once

#include "clastrace/engine/traversal.h"

#include <cmath>
#include <utility>

namespace clastrace::engine::geometry {

struct PreparedRay {
    double o[3], d[3];
    double inv[3];      // 1 / d; never read for a zero component (slab.h tests those apart)
    int kx, ky, kz;     // the watertight test's dimension permutation: kz the largest |d|
    double sx, sy, sz;  // its shear
    double tmin, tmax;  // the query interval (closed, as Vulkan's)
    TraversalMode mode;
    // kFloat32: the same ray rounded to float (o and d are then floats already), 1 / d and
    // the shear in float, as a float32 pipeline holds them.
    float fo[3], fd[3], finv[3];
    float fsx, fsy, fsz;
};

// `o` and `d` in double; for kFloat32 they must be float values (the float ray).
inline PreparedRay prepare_ray(const double o[3], const double d[3], double tmin, double tmax,
                               TraversalMode mode = TraversalMode::kDouble) {
    PreparedRay r;
    r.mode = mode;
    for (int a = 0; a < 3; ++a) {
        r.o[a] = o[a];
        r.d[a] = d[a];
        r.inv[a] = 1.0 / d[a];
        r.fo[a] = float(o[a]);
        r.fd[a] = float(d[a]);
        r.finv[a] = 1.0f / r.fd[a];
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
    r.fsx = r.fd[kx] / r.fd[kz];
    r.fsy = r.fd[ky] / r.fd[kz];
    r.fsz = 1.0f / r.fd[kz];
    r.tmin = tmin;
    r.tmax = tmax;
    return r;
}

}  // namespace clastrace::engine::geometry
