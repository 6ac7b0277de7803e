// SPDX-License-Identifier: Apache-2.0
// examples/rt_frame_loop on lavapipe 25 (label rt-driver): in every mode the last frame's image
// equals the one frame_scene.cpp traces on the CPU for that frame; under `clastrace capture` the
// layer provides VK_EXT_frame_boundary, records one FrameBoundary per frame (frame ids 0..N-1,
// after each frame's QueueSubmit), counts those marks as frames for --frames (no presents), and
// `clastrace replay` reads the trace without damage.
#include "frame_scene.h"
#include "rt_frame_loop_launch.h"

#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <regex>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using namespace clastrace::layer_launch;

constexpr uint32_t kFrames = 5, kWidth = 96, kHeight = 64;

struct TracedFrames {
    std::vector<uint64_t> submissions;  // QueueSubmit indices, in file order
    struct Boundary {
        uint64_t submission, frame_id, frame;
        uint32_t flags, carrier;
        size_t buffers;
        size_t after_submissions;  // QueueSubmit records before it in the file
    };
    std::vector<Boundary> boundaries;
};

class RtFrameLoop : public rt_frame_loop_test::RtFrameLoopLaunch {
protected:
    RtFrameLoop() : RtFrameLoopLaunch("clastrace_rt_frame_loop", kFrames, kWidth, kHeight) {}

    TracedFrames read_trace() {
        TracedFrames t;
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open((dir / "frames.clt").string(), &error);
        EXPECT_TRUE(reader) << error.message;
        if (!reader) return t;
        clastrace::traces::RecordView view;
        while (reader->next(&view)) {
            if (const auto* s = view.record->body_as_QueueSubmit())
                t.submissions.push_back(s->submission_index());
            if (const auto* b = view.record->body_as_FrameBoundary())
                t.boundaries.push_back({b->submission(), b->frame_id(), b->frame(), b->flags(),
                                        b->carrier(), b->buffers() ? b->buffers()->size() : 0u,
                                        t.submissions.size()});
        }
        EXPECT_TRUE(reader->damage().empty());
        return t;
    }
};

// Pixels of `image` that differ from the reference, edges (ambiguous pixels) left out.
size_t mismatches(const std::vector<uint32_t>& image, const rt_frame_loop::ReferenceImage& ref) {
    size_t different = 0;
    for (size_t i = 0; i < image.size(); ++i)
        if (!ref.ambiguous[i] && image[i] != ref.pixels[i]) ++different;
    return different;
}

uint64_t printed_checksum(const std::string& out) {
    std::smatch m;
    if (!std::regex_search(out, m, std::regex("checksum ([0-9a-f]{16})"))) return 0;
    return std::stoull(m[1].str(), nullptr, 16);
}

TEST_F(RtFrameLoop, LastFrameEqualsTheCpuReferenceInEveryMode) {
    const rt_frame_loop::ReferenceImage last =
        rt_frame_loop::trace_reference(kFrames - 1, kWidth, kHeight);
    const rt_frame_loop::ReferenceImage before =
        rt_frame_loop::trace_reference(kFrames - 2, kWidth, kHeight);
    ASSERT_GT(mismatches(last.pixels, before), 50u) << "the animation must change the image";
    for (const std::string mode : {"", "--single-buffered-pool", "--skip-vertex-barrier",
                                   "--single-buffered-pool --skip-vertex-barrier"}) {
        SCOPED_TRACE(mode);
        const fs::path image = dir / "last.ppm";
        fs::remove(image);
        ProcessResult r = run_alone(mode + " --image " + quote(image.string()));
        ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
        EXPECT_NE(r.out.find(mode.find("single") != std::string::npos ? "pool_slots 1"
                                                                      : "pool_slots 2"),
                  std::string::npos)
            << r.out;
        std::vector<uint32_t> pixels;
        uint32_t width = 0, height = 0;
        std::string error;
        ASSERT_TRUE(rt_frame_loop::read_ppm(image.string(), pixels, width, height, error)) << error;
        ASSERT_EQ(width, kWidth);
        ASSERT_EQ(height, kHeight);
        EXPECT_EQ(mismatches(pixels, last), 0u);
        EXPECT_GT(mismatches(pixels, before), 50u);  // the last frame, not an earlier one
        EXPECT_EQ(printed_checksum(r.out), rt_frame_loop::image_checksum(pixels)) << r.out;
    }
}

// Lavapipe 25 lacks VK_EXT_frame_boundary: the layer provides it, the program marks each frame's
// submission, and the trace holds one FrameBoundary per frame after that frame's QueueSubmit.
TEST_F(RtFrameLoop, LayerRecordsOneFrameBoundaryPerFrame) {
    ProcessResult alone = run_alone("");
    ASSERT_EQ(alone.exitCode, 0) << alone.err;
    EXPECT_NE(alone.out.find("frame_boundary off"), std::string::npos) << alone.out;

    ProcessResult r = capture("", "");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.out.find("frame_boundary on"), std::string::npos) << r.out;
    EXPECT_EQ(printed_checksum(r.out), printed_checksum(alone.out));  // the layer changes no pixel
    const TracedFrames t = read_trace();
    ASSERT_EQ(t.submissions.size(), kFrames);
    ASSERT_EQ(t.boundaries.size(), kFrames);
    for (uint32_t f = 0; f < kFrames; ++f) {
        SCOPED_TRACE(f);
        EXPECT_EQ(t.boundaries[f].frame_id, f);
        EXPECT_EQ(t.boundaries[f].frame, f);     // no presents: the marks are the frames
        EXPECT_EQ(t.boundaries[f].flags, 1u);    // VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT
        EXPECT_EQ(t.boundaries[f].carrier, 0u);  // vkQueueSubmit
        EXPECT_EQ(t.boundaries[f].buffers, 1u);
        EXPECT_EQ(t.boundaries[f].submission, t.submissions[f]);
        EXPECT_EQ(t.boundaries[f].after_submissions, f + 1u);
    }

    ProcessResult replay =
        run(std::string(CLASTRACE_CLI) + " replay --json " + quote((dir / "frames.clt").string()),
            {}, false);
    EXPECT_NE(replay.exitCode, 2) << replay.out << replay.err;
    const nlohmann::json report = nlohmann::json::parse(replay.out, nullptr, false);
    ASSERT_FALSE(report.is_discarded()) << replay.out;
    EXPECT_EQ(report.value("trace_damage", nlohmann::json::array()).size(), 0u) << replay.out;
}

// --frames counts the marks where nothing presents: frames 2-3 are the 3rd and 4th submissions,
// captured behind the pre-range prelude (the structures frames 0-1 built; capture/README.md
// "Frame ranges"), and every mark is still recorded.
TEST_F(RtFrameLoop, FrameRangeCountsFrameBoundaries) {
    ProcessResult r = capture("--frames 2-3", "--single-buffered-pool");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    const TracedFrames t = read_trace();
    ASSERT_EQ(t.submissions.size(), 3u);  // the prelude, then frames 2 and 3
    ASSERT_EQ(t.boundaries.size(), kFrames);
    // `submission` counts every submission of the process; the trace's QueueSubmits only the
    // captured ones, each right before its frame's mark.
    const size_t expected_after[kFrames] = {0, 0, 2, 3, 3};
    for (uint32_t f = 0; f < kFrames; ++f) {
        EXPECT_EQ(t.boundaries[f].submission, f) << f;
        EXPECT_EQ(t.boundaries[f].after_submissions, expected_after[f]) << f;
    }
    for (uint32_t f = 0; f < kFrames; ++f) EXPECT_EQ(t.boundaries[f].frame, f);
}

}  // namespace
