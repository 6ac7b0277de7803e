// SPDX-License-Identifier: Apache-2.0
// clastrace analyze over a trace with a secondary command buffer: a hazard whose earlier
// command sits in a secondary is tied to that command (its own ordinal), not to another
// command of the same secondary, and the command is listed under the secondary's handle.
#include "catalogue_scene.h"
#include "trace_script.h"

#include <clastrace/analyze/replay_stream.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <unistd.h>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;

TEST(AnalyzeSecondary, HazardNamesTheCommandInsideTheSecondary) {
    const std::string path = (std::filesystem::temp_directory_path() /
                              ("analyze_secondary_" + std::to_string(::getpid()) + ".clt"))
                                 .string();
    {
        TraceScript t(path, device());
        add_buffers(t);
        const std::vector<uint8_t> infos =
            bytes_of(std::vector<TriangleInfo>{triangle_info(0), triangle_info(1)});
        t.begin(0x5c01, 0, 1, 0);
        t.copy(kStagingBuffer, 0, kInfosBuffer, 0, infos.size(), {{kStaging, infos}});  // ordinal 1
        t.fill(kScratchBuffer, 0x4000, 16, 0);  // ordinal 2: unrelated
        t.end();
        t.begin(0xc100, 0, 0, 0);
        t.execute_commands({0x5c01});                        // ordinal 0
        triangle_clusters(Destinations::kImplicit).emit(t);  // ordinal 3: reads what the copy wrote
        t.end();
        t.submit_listed(0x9001, {0xc100});
        t.finish();
    }
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    analyze::TraceAnalysis a = analyze::analyze_trace(*reader, path);
    std::remove(path.c_str());
    EXPECT_EQ(a.stream.hazards_prior_unknown, 0u);
    ASSERT_EQ(a.report.hazards.size(), 1u);
    EXPECT_EQ(a.report.hazards[0].hazard.first_command, 1u);
    EXPECT_EQ(a.report.hazards[0].hazard.second_command, 3u);
    ASSERT_EQ(a.replay.hazards.size(), 1u);
    EXPECT_EQ(a.replay.hazards[0].prior.command.secondary_command, 0u);
}

}  // namespace
