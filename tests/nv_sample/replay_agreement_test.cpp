// SPDX-License-Identifier: Apache-2.0
// Replays traces/samples/h100_nv_ray_tracing.clt (captured on an H100) on clastrace's engine:
// every NV object must be rebuilt from the captured inputs, the deserialization of the
// driver's blob must be recognised as foreign, and the engine's answers for the rays the
// driver traced at capture time (RayQueryCheck) must agree with the driver's.
//
// Built only once replay/src/nv_command.cpp exists (the engine helper's NV replay, issue 8);
// the report fields used here (counts.nv_builds, counts.deserializations, ray_checks) are that
// change's.
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <string>

namespace {

using namespace clastrace;

replay::ReplayReport replaySample(
    const char* path,
    replay::RayCheckTraversal traversal = replay::RayCheckTraversal::kCapturingDevice) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    EXPECT_TRUE(reader) << error.message;
    if (!reader) return {};
    replay::ReplayOptions options;
    options.max_findings_per_rule = 100000;  // every disagreeing ray listed
    options.max_findings = 100000;
    options.ray_check_traversal = traversal;
    return replay::replay_trace(*reader, path, options);
}

const replay::ReplayReport& report() {
    static const replay::ReplayReport r = replaySample(CLASTRACE_NV_SAMPLE);
    return r;
}

TEST(NvSampleReplay, RebuildsEveryObjectAndRefit) {
    const auto& r = report();
    EXPECT_TRUE(r.trace_damage.empty());
    EXPECT_FALSE(r.engine_trace);  // the driver's own capture: outputs are not the engine's bytes
    EXPECT_EQ(r.counts.nv_builds, 6u);  // 2 bottom levels + top level, built then updated
    EXPECT_EQ(r.counts.deserializations, 1u);
    EXPECT_GE(r.counts.handles_translated, 5u);  // each instance record names a bottom level
    for (const auto& n : r.not_replayed) {
        const std::string name = n.where.name;
        EXPECT_NE(name, "vkCmdBuildAccelerationStructureNV") << n.reason;
        EXPECT_NE(name, "vkCmdCopyMemoryToAccelerationStructureKHR") << n.reason;
    }
}

TEST(NvSampleReplay, DriverBlobIsForeignButChecked) {
    bool opaque = false;  // a limit of the replay: a note, the trace stays clean
    for (const auto& n : report().notes) opaque |= n.rule == "CLASTRACE-replay-nv-opaque-object";
    EXPECT_TRUE(report().clean());
    for (const auto& f : report().findings) {
        // The blob is well formed: no header, size, alignment or handle rule may fire.
        EXPECT_EQ(f.rule.find("VUID-vkCmdCopyMemoryToAccelerationStructureKHR"), std::string::npos)
            << f.format();
    }
    EXPECT_TRUE(opaque);
}

TEST(NvSampleReplay, EveryRayAgreesWithTheDriver) {
    const auto& r = report();
    ASSERT_EQ(r.ray_checks.size(), 2u);  // after the build and after the refit
    for (const auto& c : r.ray_checks) {
        std::printf(
            "ray check after submission %llu: %llu rays, %llu hits agree, %llu misses agree, %llu "
            "ties, %llu near "
            "edges, %llu disagree, max relative t difference %.3g\n",
            (unsigned long long)c.after_submission, (unsigned long long)c.rays,
            (unsigned long long)c.agree_hit, (unsigned long long)c.agree_miss,
            (unsigned long long)c.tie, (unsigned long long)c.edge, (unsigned long long)c.disagree,
            c.max_rel_t);
        ASSERT_TRUE(c.checked) << c.why_not;
        EXPECT_EQ(c.rays, 4096u);
        EXPECT_EQ(c.disagree, 0u) << c.label;
        EXPECT_EQ(c.agree_hit + c.agree_miss + c.tie + c.edge, c.rays);
        EXPECT_GT(c.agree_hit, 1400u);            // the driver hit 1545 and 1585 of them
        EXPECT_LT(c.tie + c.edge, c.rays / 100);  // shared edges and equal-t overlaps stay rare
        EXPECT_LT(c.max_rel_t, 1e-4);
    }
    for (const auto& f : r.findings)
        EXPECT_NE(f.rule, "CLASTRACE-replay-ray-check-disagrees") << f.format();
}

// The extremes sample (traces/samples/README.md): every object still rebuilds and every ray is
// compared. Replay's ray checks trace in float32 by default, as the driver did: 0 of the 8192
// rays disagree. At 1e4 coordinates some hits still differ in t by more than 1e-5 relative
// but within the float32 error bound (NvHit::t_error), counted apart.
TEST(NvExtremesReplay, Float32TraversalAgreesWithTheDriverOnEveryRay) {
    const replay::ReplayReport r = replaySample(CLASTRACE_NV_EXTREMES);
    EXPECT_TRUE(r.trace_damage.empty());
    EXPECT_EQ(r.counts.nv_builds, 6u);
    EXPECT_EQ(r.counts.deserializations, 1u);
    ASSERT_EQ(r.ray_checks.size(), 2u);
    for (const auto& c : r.ray_checks) {
        std::printf(
            "extremes ray check after submission %llu (%s): %llu hits agree (%llu within "
            "float32 error), %llu misses agree, %llu ties, %llu near edges, %llu "
            "disagree\n",
            (unsigned long long)c.after_submission, c.traversal.c_str(),
            (unsigned long long)c.agree_hit, (unsigned long long)c.float_precision,
            (unsigned long long)c.agree_miss, (unsigned long long)c.tie, (unsigned long long)c.edge,
            (unsigned long long)c.disagree);
        ASSERT_TRUE(c.checked) << c.why_not;
        EXPECT_EQ(c.traversal, "float32");
        EXPECT_EQ(c.rays, 4096u);
        EXPECT_EQ(c.agree_hit + c.agree_miss + c.tie + c.edge + c.disagree, c.rays);
        EXPECT_GT(c.agree_hit, 1700u);  // the driver hit 1788 of each
        EXPECT_EQ(c.disagree, 0u);
    }
    for (const auto& f : r.findings)
        EXPECT_NE(f.rule, "CLASTRACE-replay-ray-check-disagrees") << f.format();
}

// The same in double (`--traversal double`): the two rays a double traversal cannot give as the
// driver did (the thin slab of the 1e-2-scaled instance seen from 4e4, and the 1e-3 triangle's
// barycentrics unless within their float bound) are named by their cause class, far/tiny.
TEST(NvExtremesReplay, DoubleTraversalNamesTheCauseOfWhatIsLeft) {
    const replay::ReplayReport r =
        replaySample(CLASTRACE_NV_EXTREMES, replay::RayCheckTraversal::kDouble);
    ASSERT_EQ(r.ray_checks.size(), 2u);
    uint64_t disagree = 0, far_tiny = 0;
    for (const auto& c : r.ray_checks) {
        ASSERT_TRUE(c.checked) << c.why_not;
        EXPECT_EQ(c.traversal, "double");
        EXPECT_EQ(c.disagree_far_tiny + c.disagree_degenerate + c.disagree_unexplained, c.disagree);
        disagree += c.disagree;
        far_tiny += c.disagree_far_tiny;
    }
    EXPECT_GE(disagree, 1u);
    EXPECT_LE(disagree, 2u);
    EXPECT_EQ(far_tiny, disagree);
    for (const auto& f : r.findings)
        if (f.rule == "CLASTRACE-replay-ray-check-disagrees") {
            EXPECT_NE(f.message.find("cause class far/tiny, double traversal"), std::string::npos)
                << f.message;
        }
}

}  // namespace
