// SPDX-License-Identifier: Apache-2.0
// The ray check's KHR tracer (ray-query compute shader) on lavapipe 25: tests/apps/
// khr_ray_query_app traces fixed rays at a two-instance KHR scene; each answer is known by hand
// (t, instance, custom index, geometry, primitive, barycentrics, hit kind, masks, t_max, culling,
// and the box rule t = max(entry, t_min)).
#include <clastrace/testsupport/test_driver.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <map>
#include <sstream>
#include <string>

namespace {

struct Answer {
    unsigned hit = 0, custom = 0, instance = 0, primitive = 0, geometry = 0, kind = 0;
    double t = 0, u = 0, v = 0;
};

std::map<int, Answer> run_app() {
    std::map<int, Answer> out;
    const auto driver = clastrace::testsupport::ray_tracing_driver();
    const std::string line = "env" + driver->environment_words() + " " KHR_RAY_QUERY_APP;
    FILE* pipe = popen(line.c_str(), "r");
    if (!pipe) return out;
    char text[512];
    while (std::fgets(text, sizeof text, pipe)) {
        std::istringstream in(text);
        std::string word;
        int ray = -1;
        Answer a;
        in >> word >> ray >> word >> a.hit >> word >> a.t >> word >> a.custom >> word >>
            a.instance >> word >> a.primitive >> word >> a.geometry >> word >> a.kind >> word >>
            a.u >> word >> a.v;
        if (in) out[ray] = a;
    }
    EXPECT_EQ(pclose(pipe), 0) << line;
    return out;
}

TEST(KhrRayTracer, AnswersFixedRaysAsTheRuleSays) {
    const auto driver = clastrace::testsupport::ray_tracing_driver();
    if (!driver) GTEST_SKIP() << clastrace::testsupport::kNoRayTracingDriver;
    const auto answers = run_app();
    ASSERT_EQ(answers.size(), 10u);
    // The quad's triangle 1 (vertices 0, 2, 3) at (0.25, 0.5): barycentrics (0.625, 0.125).
    const Answer& quad = answers.at(0);
    EXPECT_EQ(quad.hit, 1u);
    EXPECT_DOUBLE_EQ(quad.t, 5.0);
    EXPECT_EQ(quad.custom, 7u);
    EXPECT_EQ(quad.instance, 0u);
    EXPECT_EQ(quad.primitive, 1u);
    EXPECT_EQ(quad.geometry, 0u);
    EXPECT_NEAR(quad.u, 0.625, 1e-6);
    EXPECT_NEAR(quad.v, 0.125, 1e-6);
    EXPECT_EQ(answers.at(1).primitive, 0u);
    EXPECT_NEAR(answers.at(1).u, 0.125, 1e-6);
    // From below the lower triangle (geometry 1) is hit first, from its other side.
    const Answer& below = answers.at(2);
    EXPECT_EQ(below.hit, 1u);
    EXPECT_DOUBLE_EQ(below.t, 3.0);
    EXPECT_EQ(below.geometry, 1u);
    EXPECT_TRUE((quad.kind == 0xFE && below.kind == 0xFF) ||
                (quad.kind == 0xFF && below.kind == 0xFE))
        << quad.kind << " " << below.kind;
    // The box, scaled 2x at x = 5: entered at t = 4; hit kind 0, no barycentrics.
    const Answer& box = answers.at(3);
    EXPECT_EQ(box.hit, 1u);
    EXPECT_DOUBLE_EQ(box.t, 4.0);
    EXPECT_EQ(box.custom, 9u);
    EXPECT_EQ(box.instance, 1u);
    EXPECT_EQ(box.kind, 0u);
    EXPECT_EQ(box.u, 0.0);
    EXPECT_EQ(answers.at(4).hit, 0u);  // cull mask 0x01 against the box instance's 0x02
    EXPECT_EQ(answers.at(5).hit, 0u);  // t_max 4 stops short of the quad
    EXPECT_EQ(answers.at(6).hit, 0u);
    // Culling one facing removes the quad (and the lower triangle, wound the same way).
    EXPECT_NE(answers.at(7).hit, answers.at(8).hit);
    const Answer& kept = answers.at(7).hit ? answers.at(7) : answers.at(8);
    EXPECT_DOUBLE_EQ(kept.t, 5.0);
    EXPECT_EQ(kept.kind, quad.kind);
    // Inside the box: the hit is at t_min.
    EXPECT_EQ(answers.at(9).hit, 1u);
    EXPECT_DOUBLE_EQ(answers.at(9).t, 0.0);
}

}  // namespace
