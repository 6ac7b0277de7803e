// SPDX-License-Identifier: Apache-2.0
// Pre-range state (capture/README.md, "Frame ranges") on lavapipe 25 (label rt-driver):
// examples/rt_frame_loop --build-frames 2 builds its BLASes and TLASes in frames 0 and 1 only;
// frames 2 and 3 trace them. `clastrace capture --frames 2-3` must carry those structures' last
// builds as the prelude: the replay is clean, the ray queries reach both BLASes through the
// replayed top level, and the engine traces the driver's image from them. Served cluster
// builds before the range: tests/apps/cluster_capture_app serve-frames builds its clusters in
// frames 0 and 1 and the bottom level over them in frame 2.
#include "frame_scene.h"
#include "rt_frame_engine_image.h"
#include "rt_frame_loop_launch.h"

#include <clastrace/engine/nv_trace.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_generated.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace {

namespace fs = std::filesystem;
using clastrace::layer_launch::ProcessResult;
using clastrace::layer_launch::quote;
using nlohmann::json;

constexpr uint32_t kFrames = 4, kWidth = 64, kHeight = 48;
const std::string kArgs = "--build-frames 2";

// What the start of a trace says: the layer's PreRangeState record, and the submissions.
struct TraceStart {
    bool pre_range = false;
    clastrace::fbs::PreRangeStateT state;
    size_t submissions = 0;
    size_t submissions_before_state = 0;
    uint64_t next_submission_index = 0;  // of the QueueSubmit right after the record
    size_t khr_builds = 0;
    size_t cluster_builds = 0;
};

TraceStart read_start(const fs::path& trace) {
    TraceStart t;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    EXPECT_TRUE(reader) << error.message;
    if (!reader) return t;
    clastrace::traces::RecordView view;
    bool after_state = false;
    while (reader->next(&view)) {
        if (const auto* p = view.record->body_as_PreRangeState(); p && !t.pre_range) {
            t.pre_range = after_state = true;
            p->UnPackTo(&t.state);
            t.submissions_before_state = t.submissions;
        }
        if (const auto* q = view.record->body_as_QueueSubmit();
            q && std::exchange(after_state, false))
            t.next_submission_index = q->submission_index();
        t.submissions += view.kind == clastrace::fbs::RecordBody::QueueSubmit;
        t.khr_builds += view.kind == clastrace::fbs::RecordBody::CmdBuildAccelerationStructuresKHR;
        t.cluster_builds +=
            view.kind == clastrace::fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect;
    }
    return t;
}

class PreRangeState : public rt_frame_loop_test::RtFrameLoopLaunch {
protected:
    PreRangeState() : RtFrameLoopLaunch("clastrace_pre_range_state", kFrames, kWidth, kHeight) {}

    // Captures with `options` into `name` (and the driver's last image into name.ppm).
    fs::path capture_as(const std::string& name, const std::string& options) {
        const fs::path image = dir / (name + ".ppm");
        ProcessResult r = capture(options, kArgs + " --image " + quote(image.string()));
        EXPECT_EQ(r.exitCode, 0) << r.out << r.err;
        fs::rename(dir / "frames.clt", dir / name);
        return dir / name;
    }
    json replay_json(const fs::path& trace, int* exit_code) {
        ProcessResult r =
            run(std::string(CLASTRACE_CLI) + " replay --json " + quote(trace.string()), {}, false);
        *exit_code = r.exitCode;
        json report = json::parse(r.out, nullptr, false);
        EXPECT_FALSE(report.is_discarded()) << r.out << r.err;
        return report.is_discarded() ? json::object() : report;
    }
};

TEST_F(PreRangeState, FrameRangeReplaysStructuresBuiltBeforeIt) {
    const fs::path range = capture_as("range.clt", "--frames 2-3");
    const TraceStart start = read_start(range);
    // Both ring slots' BLAS pairs (one build command each) and TLASes: 6 structures, 4 commands;
    // the prelude is the first submission, then the two captured frames.
    ASSERT_TRUE(start.pre_range);
    EXPECT_EQ(start.state.structures, 6u);
    EXPECT_EQ(start.state.commands, 4u);
    EXPECT_EQ(start.state.cluster_commands, 0u);
    EXPECT_EQ(start.state.before_frame, 2u);
    EXPECT_GT(start.state.input_bytes, 0u);
    EXPECT_EQ(start.submissions_before_state, 0u);
    EXPECT_EQ(start.state.prelude_submission, 0u);
    EXPECT_EQ(start.next_submission_index, start.state.prelude_submission);
    EXPECT_EQ(start.submissions, 3u);
    EXPECT_EQ(start.khr_builds, 4u);

    int exit_code = -1;
    const json report = replay_json(range, &exit_code);
    EXPECT_EQ(exit_code, 0) << report.dump(1);
    EXPECT_EQ(report.value("findings", json::array()).size(), 0u) << report.dump(1);
    EXPECT_EQ(report.value("trace_damage", json::array()).size(), 0u) << report.dump(1);
    if (report.contains("hazards")) {
        EXPECT_EQ(report["hazards"].value("hazards", json::array()).size(), 0u) << report.dump(1);
    }

    // The engine's image of frame 3 from the replayed structures is the driver's.
    const auto engine = rt_frame_loop::replay_engine_image(range, kWidth, kHeight);
    EXPECT_EQ(engine.dispatches, 2u);
    ASSERT_TRUE(engine.errors.empty()) << engine.errors.front();
    EXPECT_EQ(engine.instances_reached, rt_frame_loop::kMeshCount);
    std::vector<uint32_t> driver;
    uint32_t width = 0, height = 0;
    std::string error;
    ASSERT_TRUE(
        rt_frame_loop::read_ppm((dir / "range.clt.ppm").string(), driver, width, height, error))
        << error;
    ASSERT_EQ(engine.pixels.size(), driver.size());
    // Frame 3 traces ring slot 1, built in frame 1: edge pixels are those of frame 1's scene.
    const rt_frame_loop::ReferenceImage built = rt_frame_loop::trace_reference(1, kWidth, kHeight);
    size_t different = 0, hits = 0;
    for (size_t i = 0; i < driver.size(); ++i) {
        if (built.ambiguous[i]) continue;
        different += engine.pixels[i] != driver[i];
        hits += engine.pixels[i] != rt_frame_loop::kBackground;
    }
    EXPECT_EQ(different, 0u);
    EXPECT_GT(hits, 100u);

    // The same image as the full capture's replay gives.
    const fs::path full = capture_as("full.clt", "");
    EXPECT_FALSE(read_start(full).pre_range);
    const auto whole = rt_frame_loop::replay_engine_image(full, kWidth, kHeight);
    EXPECT_EQ(whole.dispatches, size_t(kFrames));
    EXPECT_EQ(whole.pixels, engine.pixels);

    // `clastrace info` says the trace starts with the state from before the range.
    ProcessResult info =
        run(std::string(CLASTRACE_CLI) + " info --json " + quote(range.string()), {}, false);
    const json summary = json::parse(info.out, nullptr, false);
    ASSERT_FALSE(summary.is_discarded()) << info.out << info.err;
    const json& pre = summary["frames"]["pre_range_state"];
    EXPECT_EQ(pre.value("structures", 0), 6) << summary["frames"];
    EXPECT_EQ(pre.value("commands", 0), 4);
    EXPECT_EQ(pre.value("before_frame", 0), 2);
    EXPECT_EQ(pre.value("prelude_submission", 99), 0);
    EXPECT_GT(pre.value("bytes", 0), 0);
    EXPECT_EQ(summary["frames"]["with_submissions"],
              json::parse(R"([{"frame":2,"submissions":1},{"frame":3,"submissions":1}])"));
}

// The served scene of cluster_capture_app serve-frames under `clastrace capture` (lavapipe 25
// serves the extension through the layer).
class PreRangeClusterState : public PreRangeState {
protected:
    ProcessResult capture_served(const std::string& options, const fs::path& trace,
                                 const std::string& mode = "serve-frames") {
        return captureOnDriver(trace,
                               std::string(CLASTRACE_CAPTURE_APP) + " " + mode + " " +
                                   quote((dir / "serve-frames.json").string()),
                               "--log info " + options);
    }
};

TEST_F(PreRangeClusterState, FrameRangeReplaysClustersBuiltBeforeIt) {
    const fs::path range = dir / "clusters.clt";
    const ProcessResult r = capture_served("--frames 2-", range);
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    // Frame 1 built the clusters again over frame 0's: only its build is kept, for 3 objects.
    EXPECT_NE(r.err.find("pre-range state: 3 structures from 1 commands (1 cluster commands) "
                         "before frame 2"),
              std::string::npos)
        << r.err;
    const TraceStart start = read_start(range);
    ASSERT_TRUE(start.pre_range);
    EXPECT_EQ(start.state.cluster_commands, 1u);
    EXPECT_EQ(start.state.commands, 1u);
    EXPECT_EQ(start.state.structures, 3u);
    EXPECT_EQ(start.state.before_frame, 2u);
    EXPECT_GT(start.state.input_bytes, 0u);
    EXPECT_EQ(start.submissions, 2u);     // the prelude, frame 2
    EXPECT_EQ(start.cluster_builds, 2u);  // the clusters in the prelude, frame 2's bottom level

    // The bottom level replays over the prelude's clusters: clean, and both commands' outputs
    // are the engine's again.
    int exit_code = -1;
    const json report = replay_json(range, &exit_code);
    EXPECT_EQ(exit_code, 0) << report.dump(1);
    EXPECT_EQ(report.value("findings", json::array()).size(), 0u) << report.dump(1);
    EXPECT_EQ(report.value("trace_damage", json::array()).size(), 0u) << report.dump(1);
    EXPECT_TRUE(report.value("clean", false)) << report.dump(1);
    EXPECT_TRUE(report.value("outputs_verified", false)) << report.dump(1);
    EXPECT_GT(report["counts"].value("outputs_compared", 0), 0) << report.dump(1);
    EXPECT_EQ(report["counts"].value("cluster_commands", 0), 2) << report.dump(1);
    const json sizes = report.value("sizes", json::array());
    ASSERT_EQ(sizes.size(), 2u) << report.dump(1);
    for (const json& command : sizes) {  // the clusters, then the bottom level over them
        EXPECT_EQ(command.value("ops_compared", 0), command.value("ops", -1)) << command.dump(1);
        EXPECT_EQ(command.value("captured_bytes", 0), command.value("engine_bytes", -1));
    }
    EXPECT_EQ(sizes[0]["where"].value("command_buffer_handle", ""), "0xc1a57ace00000001");
}

// Frame 1's build waits on a timeline value the application signals only after frame 2's
// vkQueueSubmit returned: the capture the prelude needs comes after the range has started. The
// layer must not wait for it inside that submission (it once blocked there for 10 s and wrote
// the prelude without its input bytes); the trace holds the prelude until the capture comes.
TEST_F(PreRangeClusterState, APreludeWhoseCaptureComesAfterTheRangeStarted) {
    const fs::path range = dir / "gated.clt";
    const ProcessResult r = capture_served("--frames 2-", range, "serve-frames-gated");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_EQ(r.err.find("did not arrive"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("1 captures still to come, which the trace waits for"), std::string::npos)
        << r.err;
    const TraceStart start = read_start(range);
    ASSERT_TRUE(start.pre_range);
    // Frame 0's build stays too: which objects frame 1's overwrote is known only from its
    // capture, which had not come when the prelude was written. Replaying both is still right.
    EXPECT_EQ(start.state.cluster_commands, 2u);
    EXPECT_GT(start.state.input_bytes, 0u);
    EXPECT_EQ(start.cluster_builds, 3u);  // the prelude's two, frame 2's bottom level
    int exit_code = -1;
    const json report = replay_json(range, &exit_code);
    EXPECT_EQ(exit_code, 0) << report.dump(1);
    EXPECT_TRUE(report.value("clean", false)) << report.dump(1);
    EXPECT_TRUE(report.value("outputs_verified", false)) << report.dump(1);
    for (const json& command : report.value("sizes", json::array()))
        EXPECT_EQ(command.value("ops_compared", 0), command.value("ops", -1)) << command.dump(1);
}

}  // namespace
