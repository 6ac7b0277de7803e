// SPDX-License-Identifier: Apache-2.0
// The two replay fixes the bug programs asked for, pinned on hand-written traces (the programs'
// end-to-end test asserts them on real captures):
// - replay names a command by its index among the commands the application recorded: the
//   GpuTimestamp records the capture layer writes around the commands it captures do not
//   shift it (format 1.9; an older trace keeps the numbering it was written with);
// - a cluster build's read of a buffer its src infos point at (vertices, indices, cluster
//   references) is ordered by a barrier naming SHADER_READ, INDIRECT_COMMAND_READ or
//   ACCELERATION_STRUCTURE_READ (the page's readings, and NVIDIA's samples' habit); a barrier
//   naming none of them leaves it unordered.
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>

#include "file_format.h"

#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <iterator>
#include <vector>

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

// The layer's pair of timestamps around the application's fill and around its build, with no
// barrier between the two commands.
void fill_then_build_between_timestamps(TraceScript& t) {
    layer_timestamp(t, 0);
    t.fill(kInfosBuffer, 0, 0x1000, 0);  // application command 0
    layer_timestamp(t, 1);
    layer_timestamp(t, 2);
    triangle_clusters(Destinations::kImplicit).emit(t);  // application command 1
    layer_timestamp(t, 3);
}

// Rewrites a trace file's header as an older writer's of format 1.`minor`.
void set_version_minor(const std::string& path, uint16_t minor) {
    namespace f = traces::format;
    std::vector<uint8_t> file;
    {
        std::ifstream in(path, std::ios::binary);
        file.assign(std::istreambuf_iterator<char>(in), {});
    }
    ASSERT_GT(file.size(), sizeof(f::FileHeader));
    f::FileHeader fh;
    std::memcpy(&fh, file.data(), sizeof fh);
    fh.version_minor = minor;
    fh.checksum = f::file_header_checksum(fh, file.data() + sizeof fh, fh.trace_header_size);
    std::memcpy(file.data(), &fh, sizeof fh);
    std::ofstream(path, std::ios::binary | std::ios::trunc)
        .write(reinterpret_cast<const char*>(file.data()), std::streamsize(file.size()));
}

TEST(CommandIndex, TheLayersTimestampsDoNotCountAsCommands) {
    const std::string path = temp_trace_path("bug_programs", "command_index.clt");
    const replay::ReplayReport r =
        replay_catalogue_scene(path, [](TraceScript& t) { fill_then_build_between_timestamps(t); });
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

// A trace of format 1.8 or older numbered the layer's timestamps as commands (its findings and
// DeviceAddressWrites say so): replay keeps that numbering for it.
TEST(CommandIndex, ATraceOlderThanFormat19KeepsItsOwnNumbering) {
    const std::string path = temp_trace_path("bug_programs", "command_index_1_8.clt");
    {
        TraceScript t(path, device());
        add_buffers(t);
        fill_then_build_between_timestamps(t);
        t.finish();
    }
    set_version_minor(path, 8);
    const replay::ReplayReport r = replay_file(path);
    discard_trace(path);
    ASSERT_EQ(r.hazards.size(), 1u) << replay::format_text(r);
    EXPECT_EQ(r.hazards[0].prior.command.command, 1u);
    EXPECT_EQ(r.hazards[0].later.command.command, 4u);
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

// NVIDIA's cluster samples order animated vertices with ACCELERATION_STRUCTURE_READ at the build
// stage (execution_record.h): taken, not reported.
TEST(PointedInputs, ABarrierNamingAccelerationStructureReadOrdersTheVertexReads) {
    const auto r = vertices_copied_then_barrier("as_read.clt",
                                                VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    EXPECT_TRUE(r.hazards.empty()) << replay::format_text(r);
}

TEST(PointedInputs, ABarrierNamingAnUnrelatedReadDoesNot) {
    const auto r = vertices_copied_then_barrier("uniform_read.clt", VK_ACCESS_2_UNIFORM_READ_BIT);
    ASSERT_EQ(r.hazards.size(), 1u) << replay::format_text(r);
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, replay::HazardClass::kReadAfterWrite);
    EXPECT_EQ(h.later.field.rfind("srcInfosArray[", 0), 0u) << h.later.field;
    EXPECT_NE(h.later.field.find("vertexBuffer"), std::string::npos) << h.later.field;
    EXPECT_EQ(h.fix.dst_access, VK_ACCESS_2_SHADER_READ_BIT |
                                    VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT |
                                    VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
}

}  // namespace
