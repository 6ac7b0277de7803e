// SPDX-License-Identifier: Apache-2.0
// Served traceable cluster BLASes (issue 21): the capture's memory at such a BLAS holds the
// driver's BVH, marked by CmdBuildClusterAccelerationStructureIndirect.driver_bvh. Later
// snapshots over it (a host write the capture observed, a copy's input) carry the driver's bytes;
// replay keeps the engine's object there, so a later move of the BLAS still reads the engine's.
#include "catalogue_replay.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <vector>

namespace clastrace::test::catalogue {
namespace {

constexpr uint64_t kBvhSize = 0x800;  // the driver's BVH, larger than the engine's object here

replay::ReplayReport replay_blas_then_driver_bytes(bool marked) {
    // Each test writes its own file: ctest runs the two at once.
    const std::string path = temp_trace_path("driver_bvh", marked ? "marked.clt" : "unmarked.clt");
    return replay_catalogue_scene(path, [&](TraceScript& t) {
        triangle_clusters(Destinations::kExplicit).emit(t);
        t.full_barrier();
        ClusterCommand blas = bottom_level();  // the BLAS lands at kDst2
        blas.info.scratchData = kScratch2;
        if (marked) blas.driver_bvh.emplace_back(kDst2, kBvhSize);
        blas.emit(t);
        t.full_barrier();
        // The capture's copy read the driver's BVH (not the engine's bytes).
        const std::vector<uint8_t> driver_bytes(kBvhSize, 0xA5);
        t.copy(kDst2Buffer, 0, kStagingBuffer, 0, kBvhSize, {{kDst2, driver_bytes}});
        t.submit(0x9001);
        t.device_wait_idle();
        // And the host-write watch saw the BLAS's mapped pages change in the pause.
        t.host_write(kDst2, std::vector<uint8_t>(kBvhSize, 0x5A));
        ClusterCommand move = move_clusters(1);
        move.move.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV;
        move.infos = bytes_of(std::vector<uint64_t>{kDst2});
        move.info.dstImplicitData = kDst2 + 0x10000;
        move.emit(t);
        t.submit(0x9001);
    });
}

std::string findings_of(const replay::ReplayReport& r) {
    std::string s;
    for (const replay::ReplayFinding& f : r.findings) s += f.rule + ": " + f.message + "\n";
    for (const replay::HazardReport& h : r.hazards) s += h.format() + "\n";
    return s;
}

TEST(DriverBvh, LaterSnapshotsOverTheDriverBvhKeepTheEngineObject) {
    const replay::ReplayReport r = replay_blas_then_driver_bytes(true);
    EXPECT_TRUE(r.clean()) << findings_of(r);
    EXPECT_EQ(r.counts.driver_bvh_ranges, 1u);
    // The copy's input and the host write each covered the whole BVH.
    EXPECT_EQ(r.counts.driver_bvh_bytes_kept, 2 * kBvhSize);
    EXPECT_NE(replay::format_text(r).find("driver BVHs (traceable cluster BLASes) 1"),
              std::string::npos);
    EXPECT_EQ(replay::to_json(r)["counts"]["driver_bvh_bytes_kept"], 2 * kBvhSize);
}

// The same trace without the mark: the host write replaces the engine's BLAS with the driver's
// bytes and the move reads those (what replay did before driver_bvh).
TEST(DriverBvh, UnmarkedDriverBytesReplaceTheEngineObject) {
    const replay::ReplayReport r = replay_blas_then_driver_bytes(false);
    ASSERT_EQ(r.findings.size(), 1u) << findings_of(r);
    EXPECT_EQ(
        r.findings[0].rule,
        "VUID-VkClusterAccelerationStructureMoveObjectsInfoNV-srcAccelerationStructure-10483");
    EXPECT_EQ(r.counts.driver_bvh_ranges, 0u);
    EXPECT_EQ(r.counts.driver_bvh_bytes_kept, 0u);
}

}  // namespace
}  // namespace clastrace::test::catalogue
