// SPDX-License-Identifier: Apache-2.0
// The trace sink's KHR records (capture/src/trace_capture_sink.cpp) without a GPU: an indirect
// build's record carries the ranges its pause read (lavapipe 25 has no indirect builds) and its
// snapshots; a QueryPoolResults goes after the submission announced before it.
#include "clastrace/capture/capture_sink.h"

#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <vector>

namespace clastrace::capture {
namespace {

std::string tempPath(const char* name) {
    return (std::filesystem::temp_directory_path() / (std::string("clastrace_") + name + ".clt"))
        .string();
}

TEST(TraceSinkKhr, IndirectBuildCarriesTheRangesReadAtExecutionAndItsInputs) {
    const std::string path = tempPath("sink_khr_indirect");
    {
        std::string error;
        auto sink = make_trace_capture_sink(path, 3, error);
        ASSERT_TRUE(sink) << error;
        DeviceRecord device;
        device.device = 1;
        device.device_name = "test";
        sink->device_created(device);
        BufferRecord buffer;
        buffer.buffer = 0x55;
        buffer.size = 4096;
        sink->buffer_created(buffer);
        sink->buffer_bound({0x55, 0x66, 0});
        sink->buffer_address_queried({0x55, 0x10000});

        RecordedCommandBuffer cb;
        cb.command_buffer = 0x77;
        BuildAccelerationStructuresKHRCommand build;
        build.indirect = true;
        build.pause_id = 3;
        KhrBuildInfo info;
        info.info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
        info.geometries.resize(2);
        info.geometries[0].geometryType = VK_GEOMETRY_TYPE_AABBS_KHR;
        info.geometries[1].geometryType = VK_GEOMETRY_TYPE_AABBS_KHR;
        info.indirect_address = 0x10100;
        info.indirect_stride = 32;
        info.max_primitive_counts = {10, 20};
        build.infos.push_back(info);
        cb.commands.push_back(build);
        sink->command_buffer_recorded(cb);
        SubmissionRecord s;
        s.index = 1;
        s.batches.push_back({{}, {0x77}, {}});
        sink->queue_submitted(s);

        ClusterBuildCapture captured;
        captured.kind = CapturedCommandKind::kBuildAccelerationStructuresKhr;
        captured.pause_id = 3;
        captured.submission_index = 1;
        captured.command_buffer = 0x77;
        captured.khr_indirect_ranges = {{{4, 0, 0, 0}, {9, 24, 0, 0}}};
        CapturedRange ranges{MemoryRole::kBuildRanges, 0, 0x10100, {}, 0x55, 0x100};
        const std::vector<uint8_t> read(48, 7);
        ranges.bytes.assign(read.data(), read.data() + read.size());
        captured.inputs.push_back(std::move(ranges));
        sink->cluster_build_captured(std::move(captured));
        sink->query_pool_results_read({0x99, 2, {1408, 1}, 0});
    }
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    ASSERT_TRUE(reader) << error.message;
    traces::RecordView view;
    bool built = false, submitted = false, results = false;
    while (reader->next(&view)) {
        if (view.kind == fbs::RecordBody::QueueSubmit) submitted = true;
        if (const auto* r = view.record->body_as_QueryPoolResults()) {
            EXPECT_TRUE(submitted);  // after the submission announced before the call
            EXPECT_EQ(r->query_pool(), 0x99u);
            EXPECT_EQ(r->first_query(), 2u);
            ASSERT_TRUE(r->values());
            EXPECT_EQ(std::vector<uint64_t>(r->values()->begin(), r->values()->end()),
                      (std::vector<uint64_t>{1408, 1}));
            results = true;
        }
        const auto* b = view.record->body_as_CmdBuildAccelerationStructuresKHR();
        if (!b) continue;
        built = true;
        EXPECT_TRUE(b->indirect());
        EXPECT_EQ(b->command_buffer(), 0x77u);
        ASSERT_TRUE(b->infos() && b->infos()->size() == 1);
        const auto* i = b->infos()->Get(0);
        EXPECT_EQ(i->indirect_address(), 0x10100u);
        EXPECT_EQ(i->indirect_stride(), 32u);
        ASSERT_TRUE(i->max_primitive_counts());
        EXPECT_EQ(i->max_primitive_counts()->Get(1), 20u);
        ASSERT_TRUE(i->ranges());
        ASSERT_EQ(i->ranges()->size(), 2u);
        EXPECT_EQ(i->ranges()->Get(0)->primitive_count(), 4u);
        EXPECT_EQ(i->ranges()->Get(1)->primitive_count(), 9u);
        EXPECT_EQ(i->ranges()->Get(1)->primitive_offset(), 24u);
        ASSERT_TRUE(b->inputs());
        ASSERT_EQ(b->inputs()->size(), 1u);
        EXPECT_EQ(b->inputs()->Get(0)->address(), 0x10100u);
        EXPECT_EQ(b->inputs()->Get(0)->size(), 48u);
    }
    EXPECT_TRUE(built);
    EXPECT_TRUE(results);
    std::remove(path.c_str());
}

}  // namespace
}  // namespace clastrace::capture
