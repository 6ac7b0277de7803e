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
    // The origin and the shear rounded to float: the float32 tests' and the four-triangle
    // filter's (triangle4.h, both modes).
    float fo[3];
    float fsx, fsy, fsz;
    // kFloat32 only (o and d are then floats already): d and 1 / d in float, as a float32
    // pipeline holds them; the double mode reads neither, and leaves them 0.
    float fd[3] = {}, finv[3] = {};
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
    }
    if (mode == TraversalMode::kFloat32) {
        for (int a = 0; a < 3; ++a) {
            r.fd[a] = float(d[a]);
            r.finv[a] = 1.0f / r.fd[a];
        }
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
    const float fdz = float(d[kz]);
    r.fsx = float(d[kx]) / fdz;
    r.fsy = float(d[ky]) / fdz;
    r.fsz = 1.0f / fdz;
    r.tmin = tmin;
    r.tmax = tmax;
    return r;
}

}  // namespace clastrace::engine::geometry
