// SPDX-License-Identifier: Apache-2.0
// Ray sets: a pinhole camera grid (coherent) and sphere-to-box rays (random), deterministic by seed.
#pragma once

#include "clastrace/testsupport/mesh.h"

namespace clastrace::testsupport {

struct TestRay {
    Float3 origin;
    float tmin = 0.0f;
    Float3 direction;
    float tmax = 3.4028235e38f;
};

// width*height rays from a camera on the bounding sphere (direction chosen by seed) that
// frames the box.
std::vector<TestRay> camera_rays(const Bounds& box, int width, int height, uint64_t seed);
// Origins uniform on the bounding sphere (radius 1.5x half-diagonal), aimed at uniform points in the box.
std::vector<TestRay> random_rays(const Bounds& box, size_t count, uint64_t seed);

}  // namespace clastrace::testsupport
