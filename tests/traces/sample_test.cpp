// SPDX-License-Identifier: Apache-2.0
// The committed sample trace reads back clean and holds what its generator writes now.
#include "sample_scene.h"
#include "trace_test_support.h"

#include <gtest/gtest.h>

#include <map>

namespace clastrace::traces::testing {
namespace {

TEST(SampleTrace, CommittedSampleReadsCleanWithTheExpectedRecords) {
    ReadResult r = read_all(CLASTRACE_SAMPLE);
    ASSERT_TRUE(r.opened) << r.open_error.message;
    EXPECT_EQ(r.damage_count, 0u) << describe(r.damage);
    EXPECT_TRUE(r.has_index);
    std::map<fbs::RecordBody, int> counts;
    for (const fbs::RecordT& rec : r.records) ++counts[rec.body.type];
    EXPECT_EQ(counts[fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect], 1);
    EXPECT_EQ(counts[fbs::RecordBody::CmdBuildAccelerationStructureNV], 1);
    EXPECT_EQ(counts[fbs::RecordBody::CmdCopyBuffer], 1);
    EXPECT_EQ(counts[fbs::RecordBody::CmdPipelineBarrier], 2);
    EXPECT_EQ(counts[fbs::RecordBody::QueueSubmit], 1);
    EXPECT_EQ(counts[fbs::RecordBody::GpuTimestamp], 2);
    EXPECT_EQ(counts[fbs::RecordBody::BufferCreate], 10);
    // 9 snapshots, 6 distinct byte strings: the copy's input/output and the repeated vertices dedup.
    EXPECT_EQ(counts[fbs::RecordBody::MemoryContents], 6);
}

TEST(SampleTrace, CommittedSampleEqualsWhatTheGeneratorWritesNow) {
    const std::string fresh = temp_path("sample.clt");
    ASSERT_FALSE(clastrace::samples::write_sample_trace(fresh));
    ReadResult now = read_all(fresh);
    ReadResult committed = read_all(CLASTRACE_SAMPLE);
    ASSERT_TRUE(now.opened && committed.opened);
    ASSERT_EQ(now.records.size(), committed.records.size())
        << "regenerate traces/samples/sample.clt with clastrace-make-sample";
    for (size_t i = 0; i < now.records.size(); ++i) {
        EXPECT_TRUE(now.records[i] == committed.records[i])
            << "record " << i << " differs: regenerate the sample";
    }
    TraceError e;
    auto a = TraceReader::open(fresh, &e);
    auto b = TraceReader::open(CLASTRACE_SAMPLE, &e);
    ASSERT_TRUE(a && b && a->header() && b->header());
    fbs::TraceHeaderT ha, hb;
    a->header()->UnPackTo(&ha);
    b->header()->UnPackTo(&hb);
    EXPECT_TRUE(ha == hb);
}

}  // namespace
}  // namespace clastrace::traces::testing
