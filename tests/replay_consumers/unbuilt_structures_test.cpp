// SPDX-License-Identifier: Apache-2.0
// CLASTRACE-replay-structure-not-built on hand-written VK_NV_ray_tracing traces: rays over a top
// level that no command built, a top-level build over a bottom level that no command built (told
// once, not again by the rays), a clean trace, the cause a trace with a PreRangeState record
// gives, and the pre-range prelude counted in no frame.
#include "consumer_trace.h"
#include "sync_consumers.h"
#include "trace_files.h"

#include <clastrace/replay/replayer.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <functional>
#include <string>
#include <vector>

namespace clastrace::consumertest {
namespace {

using replay::ReplayFinding;
using replay::ReplayReport;

constexpr const char* kRule = "CLASTRACE-replay-structure-not-built";
constexpr uint64_t kFence = 0xF0;

std::string hex_of(uint64_t v) {
    char text[24];
    std::snprintf(text, sizeof text, "0x%llx", static_cast<unsigned long long>(v));
    return text;
}

std::vector<ReplayFinding> not_built(const ReplayReport& r) {
    std::vector<ReplayFinding> out;
    for (const ReplayFinding& f : r.findings)
        if (f.rule == kRule) out.push_back(f);
    return out;
}

std::string all_findings(const ReplayReport& r) {
    std::string s;
    for (const ReplayFinding& f : r.findings) s += f.rule + ": " + f.message + "\n";
    return s;
}

ReplayReport replay_written(const std::string& name,
                            const std::function<void(ConsumerTrace&)>& write) {
    const std::string path = test::temp_trace_path("replay_unbuilt", name);
    {
        ConsumerTrace t(path);
        write(t);
        t.finish();
    }
    ReplayReport r = test::replay_file(path, {});
    test::discard_trace(path);
    return r;
}

TEST(UnbuiltStructures, RaysOverATopLevelNoCommandBuiltAreOneFinding) {
    uint64_t tlas = 0;
    const ReplayReport r = replay_written("rays_unbuilt.clt", [&](ConsumerTrace& t) {
        const ConsumerTrace::Object top = t.top_level(1);
        tlas = top.handle;
        t.trace_rays(top);
        t.trace_rays(top);  // told once per structure
        t.submit(kFence);
        t.wait(kFence);
        t.present(0);
    });
    const auto found = not_built(r);
    ASSERT_EQ(found.size(), 1u) << all_findings(r);
    const std::string& m = found[0].message;
    // The frame is not known yet: its present comes after the submission.
    EXPECT_NE(m.find("vkCmdTraceRaysKHR (queue 0, submit 0, cb 0, cmd "), std::string::npos) << m;
    // Its own place, in the same words with the command buffer's handle and the --ops number.
    EXPECT_TRUE(found[0].format().starts_with(
        "CLASTRACE-replay-structure-not-built: vkCmdTraceRaysKHR (queue 0, submit 0, cb 0 "
        "(0xc000), cmd 0) [#0]: "))
        << found[0].format();
    EXPECT_NE(m.find("acceleration structure " + hex_of(tlas)), std::string::npos) << m;
    EXPECT_NE(m.find("built before the captured range by a capture without pre-range state"),
              std::string::npos)
        << m;
}

TEST(UnbuiltStructures, TopLevelBuiltOverABottomLevelNoCommandBuiltIsToldAtTheBuild) {
    uint64_t blas = 0, tlas = 0;
    const ReplayReport r = replay_written("top_over_unbuilt.clt", [&](ConsumerTrace& t) {
        const ConsumerTrace::Object bottom = t.bottom_level();
        const ConsumerTrace::Object top = t.top_level(1);
        blas = bottom.handle;
        tlas = top.handle;
        t.build_top(top, {bottom});
        t.barrier(kBuildStages, kStructureWrite, kRayStages, kStructureRead);
        t.trace_rays(top);  // reaches the same bottom level: not told again
        t.submit(kFence);
        t.wait(kFence);
    });
    const auto found = not_built(r);
    ASSERT_EQ(found.size(), 1u) << all_findings(r);
    const std::string& m = found[0].message;
    EXPECT_NE(m.find("vkCmdBuildAccelerationStructureNV"), std::string::npos) << m;
    EXPECT_NE(m.find("building top level " + hex_of(tlas)), std::string::npos) << m;
    EXPECT_NE(m.find("acceleration structure " + hex_of(blas)), std::string::npos) << m;
    EXPECT_NE(m.find("instance 0"), std::string::npos) << m;
}

TEST(UnbuiltStructures, EverythingBuiltBeforeTheRaysIsClean) {
    const ReplayReport r = replay_written("all_built.clt", [&](ConsumerTrace& t) {
        const ConsumerTrace::Object bottom = t.bottom_level();
        const ConsumerTrace::Object top = t.top_level(1);
        t.build_bottom(bottom);
        t.barrier(kBuildStages, kStructureWrite, kBuildStages, kStructureRead);
        t.build_top(top, {bottom});
        t.barrier(kBuildStages, kStructureWrite, kRayStages, kStructureRead);
        t.trace_rays(top);
        t.submit(kFence);
        t.wait(kFence);
    });
    EXPECT_TRUE(not_built(r).empty()) << all_findings(r);
}

// A frame range's trace: the prelude (submission 0) rebuilt the bottom level; the top level the
// rays bind is in neither the prelude nor the range.
TEST(UnbuiltStructures, ATraceWithPreRangeStateSaysThePreludeDoesNotHoldIt) {
    const ReplayReport r = replay_written("pre_range_unbuilt.clt", [&](ConsumerTrace& t) {
        const ConsumerTrace::Object bottom = t.bottom_level();
        const ConsumerTrace::Object top = t.top_level(1);
        t.pre_range_state(2, 0);
        t.build_bottom(bottom);
        t.submit(kFence);
        t.wait(kFence);
        t.trace_rays(top);
        t.submit(kFence);
        t.wait(kFence);
        t.present(2);
    });
    const auto found = not_built(r);
    ASSERT_EQ(found.size(), 1u) << all_findings(r);
    const std::string& m = found[0].message;
    EXPECT_NE(m.find("pre-range state (the builds kept from before frame 2) does not hold it"),
              std::string::npos)
        << m;
    EXPECT_NE(m.find("vkCmdTraceRaysKHR (queue 0, submit 1, "), std::string::npos) << m;
}

TEST(UnbuiltStructures, ThePreRangePreludeBelongsToNoFrame) {
    replay::detail::FrameBoundaries frames;
    frames.on_boundary(2, 2);  // frame 2 ends after submissions 0 and 1
    EXPECT_EQ(frames.frame_of(0), 2u);
    frames.on_pre_range(0);
    EXPECT_EQ(frames.frame_of(0), std::nullopt);
    EXPECT_EQ(frames.frame_of(1), 2u);
    EXPECT_EQ(frames.frame_of(2), 3u);
}

}  // namespace
}  // namespace clastrace::consumertest
