// SPDX-License-Identifier: Apache-2.0
// The two replay fixes the bug programs asked for, pinned on hand-written traces (the programs'
// end-to-end test asserts them on real captures):
// - replay names a command by its index among the commands the application recorded: the
//   GpuTimestamp records the capture layer writes around the commands it captures do not
//   shift it;
// - a cluster build's read of a buffer its src infos point at (vertices, indices, cluster
//   references) is ordered by a barrier naming SHADER_READ or INDIRECT_COMMAND_READ, the two
//   readings of the command's page; a barrier naming neither leaves it unordered.
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>

#include <gtest/gtest.h>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

// vkCmdWriteTimestamp into the layer's own query pool, as the layer records it around a build.
void layer_timestamp(TraceScript& t, uint32_t query) {
    fbs::GpuTimestampT stamp;
    stamp.command_buffer = t.command_buffer();
    stamp.query_pool = 0x9999;
    stamp.query = query;
    stamp.stage_mask = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;
    fbs::RecordT record;
    record.body.Set(std::move(stamp));
    t.command(record);
}

TEST(CommandIndex, TheLayersTimestampsDoNotCountAsCommands) {
    const std::string path = temp_trace_path("bug_programs", "command_index.clt");
    const replay::ReplayReport r = replay_catalogue_scene(path, [](TraceScript& t) {
        layer_timestamp(t, 0);               // the layer's pair around the application's fill ...
        t.fill(kInfosBuffer, 0, 0x1000, 0);  // application command 0
        layer_timestamp(t, 1);
        layer_timestamp(t, 2);  // ... and around its build, with no barrier between them
        triangle_clusters(Destinations::kImplicit).emit(t);  // application command 1
        layer_timestamp(t, 3);
    });
    ASSERT_EQ(r.hazards.size(), 1u) << replay::format_text(r);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_STREQ(h.prior.command.name, "vkCmdFillBuffer");
    EXPECT_EQ(h.prior.command.command, 0u);
    EXPECT_STREQ(h.later.command.name, "vkCmdBuildClusterAccelerationStructureIndirectNV");
    EXPECT_EQ(h.later.command.command, 1u);
    EXPECT_NE(h.format().find("(queue 0, submit 0, cb 0, cmd 1) reads srcInfosArray"),
              std::string::npos)
        << h.format();
}

// The vertices written by a copy, then a barrier to the build naming `dst_access`, then the
// build that reads them.
replay::ReplayReport vertices_copied_then_barrier(const std::string& name, uint64_t dst_access) {
    return replay_catalogue_scene(temp_trace_path("bug_programs", name), [&](TraceScript& t) {
        t.copy(kStagingBuffer, 0, kGeometryBuffer, 0, 0x300,
               {{kStaging, std::vector<uint8_t>(0x300, 0)}});
        t.barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                  VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, dst_access);
        triangle_clusters(Destinations::kImplicit).emit(t);
    });
}

TEST(PointedInputs, ABarrierNamingShaderReadOrdersTheVertexReads) {
    const auto r = vertices_copied_then_barrier("shader_read.clt", VK_ACCESS_2_SHADER_READ_BIT);
    EXPECT_TRUE(r.hazards.empty()) << replay::format_text(r);
}

TEST(PointedInputs, ABarrierNamingIndirectCommandReadOrdersTheVertexReads) {
    const auto r =
        vertices_copied_then_barrier("indirect_read.clt", VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    EXPECT_TRUE(r.hazards.empty()) << replay::format_text(r);
}

TEST(PointedInputs, ABarrierNamingAccelerationStructureReadDoesNot) {
    const auto r = vertices_copied_then_barrier("as_read.clt",
                                                VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    ASSERT_EQ(r.hazards.size(), 1u) << replay::format_text(r);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.later.field.rfind("srcInfosArray[", 0), 0u) << h.later.field;
    EXPECT_NE(h.later.field.find("vertexBuffer"), std::string::npos) << h.later.field;
    EXPECT_EQ(h.fix.dst_access,
              VK_ACCESS_2_SHADER_READ_BIT | VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
}

}  // namespace
