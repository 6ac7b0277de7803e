// SPDX-License-Identifier: Apache-2.0
// Replay names a command by its index among the commands the application recorded: the
// GpuTimestamp records the capture layer writes around the commands it captures (every
// bug_programs trace has them) do not shift it. The bug programs' end-to-end test asserts the
// same on real captures; this one pins it on a hand-written trace.
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

}  // namespace
