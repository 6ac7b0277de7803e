// SPDX-License-Identifier: Apache-2.0
// A top level reaching a cluster bottom level, and through it the CLAS it names: rays that
// bind only the top level read the CLAS, so overwriting one of them after the rays is a
// WRITE-AFTER-READ naming the path (the hazard catalogue's CLAS and BLAS, an engine trace).
#include "catalogue_scene.h"
#include "trace_files.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/trace_building/consumer_records.h>
#include <clastrace/trace_building/record_writer.h>

#include <gtest/gtest.h>

namespace clastrace::test::catalogue {
namespace {

namespace tb = trace_building;

constexpr uint64_t kRayStage = VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR;
constexpr uint64_t kBuildStage = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
constexpr uint64_t kWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr uint64_t kTopLevel = 0x7701, kTopLevelAddress = kStaging + 0x1000;

// vkCmdBuildAccelerationStructuresKHR of the top level over the packed instances at kStaging.
fbs::CmdBuildAccelerationStructuresKHRT top_level_build(uint64_t command_buffer,
                                                        uint32_t instances) {
    fbs::CmdBuildAccelerationStructuresKHRT b;
    b.command_buffer = command_buffer;
    auto info = std::make_unique<fbs::AccelerationStructureBuildInfoKHRT>();
    info->type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    info->dst = kTopLevel;
    auto geometry = std::make_unique<fbs::GeometryKHRT>();
    geometry->geometry_type = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    geometry->instances = std::make_unique<fbs::GeometryInstancesKHR>(false, kStaging);
    info->geometries.push_back(std::move(geometry));
    info->ranges.emplace_back(instances, 0, 0, 0);
    b.infos.push_back(std::move(info));
    return b;
}

replay::ReplayReport rays_then_clas_overwritten(bool barrier) {
    const std::string path = temp_trace_path("replay_consumers", "cluster_reach.clt");
    {
        TraceScript t(path, device());
        add_buffers(t);
        t.acceleration_structure(kTopLevel, kStagingBuffer, 0x1000, 0x1000);
        t.host_write(kStaging, tb::packed_instances({kDst2}));  // the cluster BLAS's address
        triangle_clusters(Destinations::kExplicit).emit(t);     // CLAS at kDst, kDst + stride
        t.barrier(kBuildStage, kWrite, kBuildStage, kRead | kWrite);
        ClusterCommand blas = bottom_level();  // lands at kDst2; its own scratch and outputs
        blas.info.scratchData = kScratch2;
        blas.info.dstAddressesArray.deviceAddress = kOut + 0x400;
        if (blas.info.dstSizesArray.deviceAddress)
            blas.info.dstSizesArray.deviceAddress = kSizes + 0x400;
        blas.emit(t);
        // Orders the bottom level's reads of the CLAS before the fill too: only the rays are not.
        t.barrier(kBuildStage, kWrite, kRayStage | kBuildStage | VK_PIPELINE_STAGE_2_CLEAR_BIT,
                  kRead);
        t.command(tb::record(top_level_build(t.command_buffer(), 1)));
        t.barrier(kBuildStage, kWrite, kRayStage, kRead);
        t.command(tb::record(
            tb::trace_rays(t.command_buffer(), {tb::structure_binding(0, kTopLevelAddress)})));
        if (barrier)
            t.barrier(kRayStage, 0, VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT);
        t.fill(kDstBuffer, kExplicitStride, 0x40, 0);  // over the second CLAS
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    discard_trace(path);
    return r;
}

TEST(ReplayConsumers, RaysThroughATopLevelReadTheClustersOfItsClusterBottomLevel) {
    const replay::ReplayReport r = rays_then_clas_overwritten(false);
    std::string all;
    for (const auto& h : r.hazards) all += h.format() + "\n";
    ASSERT_EQ(r.hazards.size(), 1u) << all;
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kWriteAfterRead) << all;
    EXPECT_STREQ(h.prior.command.name, "vkCmdTraceRaysKHR");
    EXPECT_STREQ(h.later.command.name, "vkCmdFillBuffer");
    EXPECT_NE(h.prior.field.find("top level 0x7701 > instance 0: cluster bottom level 0x10040000 "
                                 "> cluster 1: CLAS 0x10021000"),
              std::string::npos)
        << h.prior.field;
    EXPECT_TRUE(rays_then_clas_overwritten(true).hazards.empty());
}

// A top-level build over the cluster BLAS at kDst2 reads its bytes (the whole room its explicit
// destination gave it, as a KHR BLAS's object), so rebuilding that BLAS after the top level with
// nothing ordering the two is a WRITE-AFTER-READ whose reader is the top-level build; an
// execution barrier from the build stage to the build stage orders them (rt_frame_loop
// `--cluster-blas`: the next frame's CLAS build -> BLAS build barrier is one).
constexpr uint32_t kRoom = 0x800;  // the cluster BLAS's explicit room: more than its object

replay::ReplayReport top_level_then_blas_rebuilt(bool barrier) {
    const std::string path = temp_trace_path("replay_consumers", "cluster_blas_top_level.clt");
    {
        TraceScript t(path, device());
        add_buffers(t);
        t.acceleration_structure(kTopLevel, kStagingBuffer, 0x1000, 0x1000,
                                 VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
        t.host_write(kStaging, tb::packed_instances({kDst2}));
        triangle_clusters(Destinations::kExplicit).emit(t);
        t.barrier(kBuildStage, kWrite, kBuildStage, kRead | kWrite);
        auto blas = [&] {  // at the explicit destination kDst2, with a 0x800-byte room
            ClusterCommand b = bottom_level();
            b.info.input.opMode =
                VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
            b.info.dstImplicitData = 0;
            b.info.scratchData = kScratch2;
            b.info.dstAddressesArray = {kOut + 0x400, 8, 8};
            b.info.dstSizesArray = {kSizes + 0x400, 4, 4};
            b.inputs.push_back({kOut + 0x400, bytes_of(std::vector<uint64_t>{kDst2})});
            b.inputs.push_back({kSizes + 0x400, bytes_of(std::vector<uint32_t>{kRoom})});
            return b;
        };
        blas().emit(t);
        t.barrier(kBuildStage, kWrite, kBuildStage, kRead | kWrite);
        fbs::CmdBuildAccelerationStructuresKHRT top = top_level_build(t.command_buffer(), 1);
        top.infos[0]->scratch_address = kScratch2 + 0x100;
        t.command(tb::record(top));
        t.submit(0x9001);
        if (barrier) t.barrier(kBuildStage, 0, kBuildStage, 0);
        blas().emit(t);
        t.finish();
    }
    replay::ReplayReport r = replay_file(path);
    discard_trace(path);
    return r;
}

TEST(ReplayConsumers, ATopLevelBuildReadsItsClusterBottomLevelsWholeRoom) {
    const replay::ReplayReport r = top_level_then_blas_rebuilt(false);
    std::string all;
    for (const auto& h : r.hazards) all += h.format() + "\n";
    for (const replay::ReplayFinding& f : r.findings)  // the hazard only
        EXPECT_EQ(f.rule.rfind("SYNC-HAZARD-", 0), 0u) << replay::format_text(r);
    ASSERT_EQ(r.hazards.size(), 1u) << all;
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kWriteAfterRead) << all;
    EXPECT_STREQ(h.prior.command.name, "vkCmdBuildAccelerationStructuresKHR");
    EXPECT_NE(h.prior.field.find("accelerationStructureReference"), std::string::npos)
        << h.prior.field;
    EXPECT_STREQ(h.later.command.name, "vkCmdBuildClusterAccelerationStructureIndirectNV");
    // The read spans what the rebuild writes there: the BLAS's whole room, not only the
    // engine's object at its start.
    EXPECT_EQ(h.prior.range.begin, kDst2) << all;
    EXPECT_EQ(h.prior.range.end, h.later.range.end) << all;
    EXPECT_EQ(h.prior.range.end, kDst2 + kRoom) << all;
    EXPECT_TRUE(top_level_then_blas_rebuilt(true).hazards.empty());
}

}  // namespace
}  // namespace clastrace::test::catalogue
