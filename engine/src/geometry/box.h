// SPDX-License-Identifier: Apache-2.0
// The engine's one axis-aligned box: the builders' item and node bounds, the NV object
// boxes and the traversals' node boxes all use it.
#pragma once

#include <algorithm>
#include <limits>

namespace clastrace::engine::geometry {

struct Box {
    float lo[3] = {std::numeric_limits<float>::infinity(), std::numeric_limits<float>::infinity(),
                   std::numeric_limits<float>::infinity()};
    float hi[3] = {-std::numeric_limits<float>::infinity(), -std::numeric_limits<float>::infinity(),
                   -std::numeric_limits<float>::infinity()};

    static Box empty() { return Box{}; }
    // NaN in `b` is ignored (std::min/max keep their first argument when comparing with NaN).
    void grow(const Box& b) {
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], b.lo[a]);
            hi[a] = std::max(hi[a], b.hi[a]);
        }
    }
    void grow_point(const float p[3]) {
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], p[a]);
            hi[a] = std::max(hi[a], p[a]);
        }
    }
    // False for the empty box and for any NaN bound.
    bool valid() const { return lo[0] <= hi[0] && lo[1] <= hi[1] && lo[2] <= hi[2]; }
    // Half the surface area, evaluated in T (float or double; the builders' costs keep their
    // own precision); 0 for a box that is not valid; inf for unbounded ones.
    template <class T>
    T half_area() const {
        if (!valid()) return T(0);
        const T dx = T(hi[0]) - T(lo[0]), dy = T(hi[1]) - T(lo[1]), dz = T(hi[2]) - T(lo[2]);
        return dx * dy + dy * dz + dz * dx;
    }
};

}  // namespace clastrace::engine::geometry
