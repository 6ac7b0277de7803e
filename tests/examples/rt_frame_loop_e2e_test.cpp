// SPDX-License-Identifier: Apache-2.0
// examples/rt_frame_loop end to end on lavapipe 25 (label rt-driver): 4 frames captured under
// `clastrace capture` with each bug flag, `clastrace replay --json` -> exactly the hazards of
// examples/rt_frame_loop/README.md ("What the E2E checks"), and none else; without a flag the
// replay is clean (exit 0) and the image the engine traces through the replayed top level of the
// last frame equals the pixels the driver traced.
#include "frame_scene.h"
#include "rt_frame_engine_image.h"
#include "rt_frame_loop_launch.h"

#include <clastrace/engine/nv_trace.h>
#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_generated.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <set>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using clastrace::layer_launch::ProcessResult;
using clastrace::layer_launch::quote;
using nlohmann::json;

constexpr uint32_t kFrames = 4, kWidth = 96, kHeight = 64;
// 2 meshes x 6 vertices x 12 bytes (R32G32B32_SFLOAT): the ring slot's whole vertex buffer.
constexpr uint64_t kVertexBytes = 144;

// A stage or access list of the JSON report (an array of names or one "A|B" string) holds `name`.
bool has(const json& names, const std::string& name) {
    if (names.is_string()) return names.get<std::string>().find(name) != std::string::npos;
    return std::find(names.begin(), names.end(), name) != names.end();
}

uint64_t hex_value(const json& s) { return std::stoull(s.get<std::string>(), nullptr, 16); }

uint64_t overlap_bytes(const json& hazard) {
    return hex_value(hazard["overlap"][1]) - hex_value(hazard["overlap"][0]);
}

class RtFrameLoopE2e : public rt_frame_loop_test::RtFrameLoopLaunch {
protected:
    RtFrameLoopE2e() : RtFrameLoopLaunch("clastrace_rt_frame_loop_e2e", kFrames, kWidth, kHeight) {}

    // Captures the program with `args` and replays the trace; the replay's JSON report.
    json capture_and_replay(const std::string& args, int* replay_exit) {
        ProcessResult r = capture("", args);
        EXPECT_EQ(r.exitCode, 0) << r.out << r.err;
        ProcessResult replay = run(std::string(CLASTRACE_CLI) + " replay --json " +
                                       quote((dir / "frames.clt").string()),
                                   {}, false);
        *replay_exit = replay.exitCode;
        json report = json::parse(replay.out, nullptr, false);
        EXPECT_FALSE(report.is_discarded()) << replay.out << replay.err;
        if (report.is_discarded()) return json::object();
        EXPECT_EQ(report.value("trace_damage", json::array()).size(), 0u) << replay.out;
        EXPECT_EQ(report.value("findings", json::array()).size(), 0u) << replay.out;
        return report;
    }
    void expect_engine_traces_the_drivers_image(const std::string& args);
    // Captures the program with `args` and replays it: exit 0, clean, no hazard.
    void expect_clean_replay(const std::string& args);
};

json hazards_of(const json& report) {
    if (!report.contains("hazards")) return json::array();
    return report["hazards"].value("hazards", json::array());
}

void RtFrameLoopE2e::expect_clean_replay(const std::string& args) {
    int exit_code = -1;
    const json report = capture_and_replay(args, &exit_code);
    EXPECT_EQ(exit_code, 0) << report.dump(1);
    EXPECT_TRUE(report.value("clean", false));
    EXPECT_EQ(hazards_of(report).size(), 0u) << report.dump(1);
}

constexpr const char* kKhrBuild = "vkCmdBuildAccelerationStructuresKHR";
constexpr const char* kClusterBuild = "vkCmdBuildClusterAccelerationStructureIndirectNV";

// --skip-vertex-barrier's hazard (README table): the frame's BLAS build (`reader`: with
// --cluster-blas the CLAS build) reads the vertex buffer its copy wrote, with no barrier between
// them. Returns the frame.
uint64_t expect_vertex_hazard(const json& h, const std::string& reader = kKhrBuild) {
    EXPECT_EQ(h["class"].get<std::string>(), "READ-AFTER-WRITE");
    EXPECT_EQ(h["message"].get<std::string>().rfind("SYNC-HAZARD-READ-AFTER-WRITE: ", 0), 0u);
    EXPECT_FALSE(h["possible"].get<bool>());
    const json &prior = h["prior"], &later = h["later"];
    EXPECT_EQ(prior["command"].get<std::string>(), "vkCmdCopyBuffer");
    EXPECT_TRUE(prior["write"].get<bool>());
    EXPECT_TRUE(has(prior["access"], "TRANSFER_WRITE")) << prior["access"];
    EXPECT_EQ(later["command"].get<std::string>(), reader);
    EXPECT_TRUE(has(later["stage"], "ACCELERATION_STRUCTURE_BUILD")) << later["stage"];
    EXPECT_TRUE(has(later["access"], "SHADER_READ")) << later["access"];
    // One command buffer, one frame.
    EXPECT_EQ(prior["submission"], later["submission"]);
    EXPECT_EQ(prior["command_buffer_handle"], later["command_buffer_handle"]);
    EXPECT_EQ(prior["frame"], later["frame"]);
    EXPECT_EQ(overlap_bytes(h), kVertexBytes);
    const json& fix = h["fix"];
    EXPECT_EQ(fix["kind"].get<std::string>(), "pipeline_barrier");
    EXPECT_TRUE(has(fix["srcAccessMask"], "VK_ACCESS_2_TRANSFER_WRITE_BIT")) << fix;
    EXPECT_TRUE(
        has(fix["dstStageMask"], "VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR"))
        << fix;
    EXPECT_TRUE(has(fix["dstAccessMask"], "VK_ACCESS_2_SHADER_READ_BIT")) << fix;
    return prior.value("frame", uint64_t(~0ull));
}

// --single-buffered-pool's hazard: frame N's rays (or its TLAS build) read the pool's BLASes that
// frame N+1's BLAS build (`builder`: KHR, or the cluster BLAS build with --cluster-blas)
// overwrites, nothing ordering the read first. Returns frame N+1.
uint64_t expect_pool_hazard(const json& h, std::set<std::string>& readers,
                            const std::string& builder = kKhrBuild) {
    EXPECT_EQ(h["class"].get<std::string>(), "WRITE-AFTER-READ");
    EXPECT_EQ(h["message"].get<std::string>().rfind("SYNC-HAZARD-WRITE-AFTER-READ: ", 0), 0u);
    EXPECT_FALSE(h["possible"].get<bool>());
    const json &prior = h["prior"], &later = h["later"];
    readers.insert(prior["command"].get<std::string>());
    const std::string reader = prior["command"].get<std::string>();
    EXPECT_TRUE(reader == "vkCmdDispatch" || reader == "vkCmdBuildAccelerationStructuresKHR")
        << reader;
    EXPECT_TRUE(has(prior["access"], "ACCELERATION_STRUCTURE_READ")) << prior["access"];
    EXPECT_EQ(later["command"].get<std::string>(), builder);
    EXPECT_TRUE(has(later["stage"], "ACCELERATION_STRUCTURE_BUILD")) << later["stage"];
    EXPECT_TRUE(has(later["access"], "ACCELERATION_STRUCTURE_WRITE")) << later["access"];
    EXPECT_NE(prior["submission"], later["submission"]);
    EXPECT_EQ(later.value("frame", 0ull), prior.value("frame", 0ull) + 1);
    // The frame-level fix comes with the rays' read; the TLAS build's report names the barrier.
    const std::string advice = h["fix"]["advice"];
    if (reader == "vkCmdDispatch") {
        EXPECT_NE(advice.find("wait for the fence of frame " +
                              std::to_string(prior.value("frame", 0ull))),
                  std::string::npos)
            << advice;
        EXPECT_NE(advice.find("double-buffer the pool"), std::string::npos) << advice;
    }
    // A write after a read needs only an execution dependency: reader's stage -> the build.
    EXPECT_TRUE(has(h["fix"]["srcStageMask"],
                    reader == "vkCmdDispatch" ? "COMPUTE_SHADER" : "ACCELERATION_STRUCTURE_BUILD"))
        << h["fix"];
    EXPECT_TRUE(has(h["fix"]["dstStageMask"], "ACCELERATION_STRUCTURE_BUILD")) << h["fix"];
    return later.value("frame", uint64_t(~0ull));
}

TEST_F(RtFrameLoopE2e, WithoutFlagsTheReplayIsClean) { expect_clean_replay(""); }

TEST_F(RtFrameLoopE2e, SkipVertexBarrierIsOneReadAfterWritePerFrame) {
    int exit_code = -1;
    const json report = capture_and_replay("--skip-vertex-barrier", &exit_code);
    EXPECT_EQ(exit_code, 1);
    const json hazards = hazards_of(report);
    ASSERT_EQ(hazards.size(), kFrames) << report.dump(1);
    std::multiset<uint64_t> frames;
    for (const json& h : hazards) frames.insert(expect_vertex_hazard(h));
    EXPECT_EQ(frames, (std::multiset<uint64_t>{0, 1, 2, 3}));
}

TEST_F(RtFrameLoopE2e, SingleBufferedPoolIsWriteAfterReadFromFrameOne) {
    int exit_code = -1;
    const json report = capture_and_replay("--single-buffered-pool", &exit_code);
    EXPECT_EQ(exit_code, 1);
    const json hazards = hazards_of(report);
    ASSERT_EQ(hazards.size(), 2 * (kFrames - 1)) << report.dump(1);
    std::multiset<uint64_t> frames;
    std::set<std::string> readers;
    for (const json& h : hazards) frames.insert(expect_pool_hazard(h, readers));
    EXPECT_EQ(frames, (std::multiset<uint64_t>{1, 1, 2, 2, 3, 3}));
    EXPECT_EQ(readers,
              (std::set<std::string>{"vkCmdDispatch", "vkCmdBuildAccelerationStructuresKHR"}));
}

TEST_F(RtFrameLoopE2e, BothFlagsAreTheUnionOfTheRows) {
    int exit_code = -1;
    const json report =
        capture_and_replay("--skip-vertex-barrier --single-buffered-pool", &exit_code);
    EXPECT_EQ(exit_code, 1);
    const json hazards = hazards_of(report);
    ASSERT_EQ(hazards.size(), kFrames + 2 * (kFrames - 1)) << report.dump(1);
    std::multiset<uint64_t> vertex_frames, pool_frames;
    std::set<std::string> readers;
    for (const json& h : hazards) {
        if (h["class"].get<std::string>() == "READ-AFTER-WRITE")
            vertex_frames.insert(expect_vertex_hazard(h));
        else
            pool_frames.insert(expect_pool_hazard(h, readers));
    }
    EXPECT_EQ(vertex_frames, (std::multiset<uint64_t>{0, 1, 2, 3}));
    EXPECT_EQ(pool_frames, (std::multiset<uint64_t>{1, 1, 2, 2, 3, 3}));
}

// Captures the program with `args` and its last image, and traces that frame on the engine from
// the replayed trace: the same pixels as the driver's, but for rounding at triangle edges.
void RtFrameLoopE2e::expect_engine_traces_the_drivers_image(const std::string& args) {
    const fs::path image = dir / "last.ppm";
    ProcessResult r = capture("", args + " --image " + quote(image.string()));
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    std::vector<uint32_t> driver;
    uint32_t width = 0, height = 0;
    std::string error;
    ASSERT_TRUE(rt_frame_loop::read_ppm(image.string(), driver, width, height, error)) << error;
    ASSERT_EQ(width * height, kWidth * kHeight);

    const auto engine = rt_frame_loop::replay_engine_image(dir / "frames.clt", kWidth, kHeight);
    EXPECT_EQ(engine.dispatches, kFrames);
    EXPECT_TRUE(engine.errors.empty()) << engine.errors.front();
    EXPECT_EQ(engine.instances_reached, rt_frame_loop::kMeshCount);
    ASSERT_EQ(engine.pixels.size(), driver.size());

    // Edge pixels (a ray within a rounding error of a triangle's edge) may go either way.
    const rt_frame_loop::ReferenceImage last =
        rt_frame_loop::trace_reference(kFrames - 1, kWidth, kHeight);
    const rt_frame_loop::ReferenceImage before =
        rt_frame_loop::trace_reference(kFrames - 2, kWidth, kHeight);
    size_t different = 0, edges = 0, hits = 0, not_before = 0;
    for (size_t i = 0; i < driver.size(); ++i) {
        if (last.ambiguous[i]) {
            edges += engine.pixels[i] != driver[i];
            continue;
        }
        different += engine.pixels[i] != driver[i];
        hits += engine.pixels[i] != rt_frame_loop::kBackground;
        not_before += !before.ambiguous[i] && engine.pixels[i] != before.pixels[i];
    }
    EXPECT_EQ(different, 0u) << edges << " edge pixels differ too";
    EXPECT_GT(hits, 100u);       // the scene is in the picture
    EXPECT_GT(not_before, 50u);  // the last frame's structures, not the frame before's
    RecordProperty("edge_pixels_different", std::to_string(edges));
}

TEST_F(RtFrameLoopE2e, EngineTracesTheDriversImageFromTheReplayedStructures) {
    expect_engine_traces_the_drivers_image("");
}

// --cluster-blas (README "Cluster BLASes"): the layer serves the extension and, on lavapipe 25,
// builds the driver's BLAS at each cluster BLAS's address, so the program's own TLAS and rays
// traverse them.
TEST_F(RtFrameLoopE2e, ClusterBlasWithoutFlagsTheReplayIsClean) {
    expect_clean_replay("--cluster-blas");
}

TEST_F(RtFrameLoopE2e, ClusterBlasSkipVertexBarrierIsOneReadAfterWritePerFrame) {
    int exit_code = -1;
    const json report = capture_and_replay("--cluster-blas --skip-vertex-barrier", &exit_code);
    EXPECT_EQ(exit_code, 1);
    const json hazards = hazards_of(report);
    ASSERT_EQ(hazards.size(), kFrames) << report.dump(1);
    std::multiset<uint64_t> frames;
    for (const json& h : hazards) frames.insert(expect_vertex_hazard(h, kClusterBuild));
    EXPECT_EQ(frames, (std::multiset<uint64_t>{0, 1, 2, 3}));
}

TEST_F(RtFrameLoopE2e, ClusterBlasEngineTracesTheDriversImage) {
    expect_engine_traces_the_drivers_image("--cluster-blas");
}

// --cluster-blas --implicit: the cluster BLASes at implicit destinations (the common path of the
// extension), their addresses copied into the instances on the GPU. Under the layer's default
// mode each object gets room for the driver's BLAS (implicit_object_room, recorded), so the
// driver's rays traverse them and replay still compares the outputs byte for byte.
TEST_F(RtFrameLoopE2e, ClusterBlasImplicitReplayIsClean) {
    expect_clean_replay("--cluster-blas --implicit");
}

TEST_F(RtFrameLoopE2e, ClusterBlasImplicitEngineTracesTheDriversImage) {
    expect_engine_traces_the_drivers_image("--cluster-blas --implicit");
}

// The cluster BLAS pool with one slot: per frame pair one report, frame N's rays against frame
// N+1's cluster BLAS build over both explicit destinations' rooms. Frame N's TLAS build reads
// the BLASes too, but frame N+1's CLAS build -> BLAS build barrier (build stage to build stage)
// orders it before the rebuild (README; tests/replay_consumers/cluster_reach_test.cpp has the
// unordered case).
TEST_F(RtFrameLoopE2e, ClusterBlasSingleBufferedPoolIsWriteAfterReadFromFrameOne) {
    int exit_code = -1;
    const json report = capture_and_replay("--cluster-blas --single-buffered-pool", &exit_code);
    EXPECT_EQ(exit_code, 1);
    const json hazards = hazards_of(report);
    ASSERT_EQ(hazards.size(), kFrames - 1) << report.dump(1);
    std::multiset<uint64_t> frames;
    std::set<std::string> readers;
    for (const json& h : hazards) {
        frames.insert(expect_pool_hazard(h, readers, kClusterBuild));
        EXPECT_NE(h["prior"]["field"].get<std::string>().find("cluster bottom level"),
                  std::string::npos)
            << h["prior"]["field"];
        EXPECT_EQ(h["later"]["field"].get<std::string>(), "*dstAddressesArray[*]");
    }
    EXPECT_EQ(frames, (std::multiset<uint64_t>{1, 2, 3}));
    EXPECT_EQ(readers, (std::set<std::string>{"vkCmdDispatch"}));
}

}  // namespace
