// SPDX-License-Identifier: Apache-2.0
#include "clastrace/testsupport/rays.h"

#include <cmath>
#include <random>

namespace clastrace::testsupport {
namespace {

Float3 sub(const Float3& a, const Float3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Float3 cross(const Float3& a, const Float3& b) {
    return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
Float3 normalized(const Float3& a) {
    const float l = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    return {a[0] / l, a[1] / l, a[2] / l};
}
Float3 random_unit(std::mt19937_64& rng) {
    std::normal_distribution<float> n(0.0f, 1.0f);
    Float3 v;
    do {
        v = {n(rng), n(rng), n(rng)};
    } while (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] < 1e-6f);
    return normalized(v);
}

}  // namespace

std::vector<TestRay> camera_rays(const Bounds& box, int width, int height, uint64_t seed) {
    std::mt19937_64 rng(seed);
    const Float3 c = box.center();
    const float radius = 0.5f * box.diagonal();
    const Float3 dir = random_unit(rng);
    const Float3 eye{c[0] + dir[0] * 2.5f * radius, c[1] + dir[1] * 2.5f * radius,
                     c[2] + dir[2] * 2.5f * radius};
    const Float3 forward = normalized(sub(c, eye));
    Float3 up_hint{0, 1, 0};
    if (std::fabs(forward[1]) > 0.9f) up_hint = {1, 0, 0};
    const Float3 right = normalized(cross(forward, up_hint));
    const Float3 up = cross(right, forward);
    const float half = 0.45f;  // tan of half the field of view: the sphere fills the frame
    std::vector<TestRay> rays;
    rays.reserve(size_t(width) * height);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            const float sx = ((x + 0.5f) / width * 2 - 1) * half,
                        sy = ((y + 0.5f) / height * 2 - 1) * half;
            TestRay r;
            r.origin = eye;
            r.direction = normalized({forward[0] + sx * right[0] + sy * up[0],
                                      forward[1] + sx * right[1] + sy * up[1],
                                      forward[2] + sx * right[2] + sy * up[2]});
            rays.push_back(r);
        }
    return rays;
}

std::vector<TestRay> random_rays(const Bounds& box, size_t count, uint64_t seed) {
    std::mt19937_64 rng(seed);
    const Float3 c = box.center();
    const float radius = 0.75f * box.diagonal();
    std::uniform_real_distribution<float> u01(0.0f, 1.0f);
    std::vector<TestRay> rays(count);
    for (TestRay& r : rays) {
        const Float3 d = random_unit(rng);
        r.origin = {c[0] + d[0] * radius, c[1] + d[1] * radius, c[2] + d[2] * radius};
        const Float3 target{box.lo[0] + u01(rng) * (box.hi[0] - box.lo[0]),
                            box.lo[1] + u01(rng) * (box.hi[1] - box.lo[1]),
                            box.lo[2] + u01(rng) * (box.hi[2] - box.lo[2])};
        r.direction = normalized(sub(target, r.origin));
    }
    return rays;
}

}  // namespace clastrace::testsupport
