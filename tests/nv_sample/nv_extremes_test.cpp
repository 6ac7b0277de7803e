// SPDX-License-Identifier: Apache-2.0
// traces/samples/h100_nv_extremes.clt: nv_ray_tracing_app --extremes captured on the H100
// (traces/samples/README.md): a 2.4e4-wide floor triangle far below, a 1e-3 triangle, a
// degenerate and a NaN triangle, a quad split along a shared edge; a zero-thickness, a NaN, a
// 1e-3, two identical and a 2000-wide box; a mirrored, a 1e-2-scaled and a 1000-away instance.
// What the driver answered at these extremes is the reference replay must meet.
#include "sample_trace.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>

namespace {

using namespace clastrace;
using namespace clastrace::nv_sample;

const Sample& sample() {
    static const Sample s = loadSample(CLASTRACE_NV_EXTREMES);
    return s;
}

TEST(NvExtremesSample, HoldsTheBuildsRefitsDeserializationAndChecks) {
    const Sample& s = sample();
    ASSERT_TRUE(s.reader) << CLASTRACE_NV_EXTREMES;
    EXPECT_EQ(s.reader->damage_count(), 0u);
    EXPECT_LT(s.reader->stats().file_size, 2u << 20);
    ASSERT_EQ(s.builds.size(), 6u);
    ASSERT_EQ(s.checks.size(), 2u);
    EXPECT_EQ(s.copies.size(), 1u);
    for (const auto& c : s.checks) {
        EXPECT_EQ(c.rays.size(), 4096u);
        EXPECT_EQ(c.results.size(), 4096u);
    }
}

TEST(NvExtremesSample, CapturedVerticesKeepTheNaNAndTheExtremeCoordinates) {
    const Sample& s = sample();
    ASSERT_GE(s.builds.size(), 1u);
    // Geometry 0's vertices: 16 of them, 16-byte stride, the last without padding.
    const std::vector<uint8_t>* vertices = nullptr;
    for (const auto& [hash, bytes] : s.builds[0].inputs)
        if (bytes.size() == 15 * 16 + 12) vertices = &bytes;
    ASSERT_TRUE(vertices);
    auto at = [&](int vertex, int axis) {
        float f;
        std::memcpy(&f, vertices->data() + 16 * vertex + 4 * axis, 4);
        return f;
    };
    EXPECT_EQ(at(0, 0), -1e4f);
    EXPECT_EQ(at(4, 0), 1e-3f);
    EXPECT_TRUE(std::isnan(at(9, 0)));
}

TEST(NvExtremesSample, InactiveAndDegeneratePrimitivesAreNeverHit) {
    const Sample& s = sample();
    uint32_t floorHits = 0, farHits = 0, tinyInstanceHits = 0, mirroredHits = 0;
    for (const auto& c : s.checks)
        for (size_t i = 0; i < c.results.size(); ++i) {
            const auto& h = c.results[i];
            if (!h.hit()) continue;
            ASSERT_LT(h.instance_id(), 4u) << "instance 4 has mask 0";
            const bool boxes = h.instance_id() == 2 || h.instance_id() == 3;
            if (boxes) {
                EXPECT_NE(h.primitive_id(), 2u) << "ray " << i << " hit the NaN box";
                tinyInstanceHits += h.instance_id() == 2;
                farHits += h.instance_id() == 3;
            } else if (h.geometry_index() == 0) {
                EXPECT_NE(h.primitive_id(), 2u) << "ray " << i << " hit the degenerate triangle";
                EXPECT_NE(h.primitive_id(), 3u) << "ray " << i << " hit the NaN triangle";
                floorHits += h.primitive_id() == 0 && h.t() > 0;
                mirroredHits += h.instance_id() == 1;
            }
            EXPECT_TRUE(std::isfinite(h.t())) << i;
        }
    std::printf("hits: floor %u, far instance %u, 1e-2 instance %u, mirrored instance %u\n",
                floorHits, farHits, tinyInstanceHits, mirroredHits);
    // The rays reach every kind of instance the scene has.
    EXPECT_GT(floorHits, 100u);
    EXPECT_GT(farHits, 10u);
    EXPECT_GT(tinyInstanceHits, 10u);
    EXPECT_GT(mirroredHits, 10u);
}

}  // namespace
