// SPDX-License-Identifier: Apache-2.0
// The analyzer keeps bounded lists however long the trace: caps hold, totals stay exact.
#include <gtest/gtest.h>

#include "synthetic_input.h"

namespace clastrace::analyze {
namespace {

TEST(AnalyzerLimits, ListsStayBoundedAndTotalsStayExact) {
    AnalyzerLimits limits;
    limits.max_listed_commands = 16;
    limits.top_commands = 5;
    limits.timeline_buckets = 8;
    limits.max_tracked_regions = 40;
    limits.max_listed_overlaps = 10;
    limits.max_listed_hazards = 3;
    limits.recent_command_rows = 8;
    Analyzer a("limits", limits);
    synthetic::StreamShape shape;
    shape.commands = 1000;
    shape.ops_per_command = 4;
    shape.commands_per_submission = 4;
    synthetic::feed_stream(a, shape);
    AnalysisReport r = a.finish();

    EXPECT_EQ(r.commands, 1000u);
    EXPECT_EQ(r.submissions, 250u);
    EXPECT_EQ(r.ops, 4000u);
    EXPECT_EQ(r.objects, 4000u);
    EXPECT_EQ(r.sizes(OpType::kBuildTriangleCluster).engine_bytes.count(), 4000u);

    // 16 first commands plus the second commands of the 3 listed hazards (64, 128, 192) and
    // their first commands (60, 124, 188), still in the recent rows.
    EXPECT_EQ(r.commands_listed.size(), 22u);
    EXPECT_EQ(r.commands_not_listed, 1000u - 22u);
    for (std::size_t i = 1; i < r.commands_listed.size(); ++i)
        EXPECT_LT(r.commands_listed[i - 1].ordinal, r.commands_listed[i].ordinal);

    EXPECT_EQ(r.top_by_replay.size(), 5u);
    for (std::size_t i = 1; i < r.top_by_replay.size(); ++i)
        EXPECT_GE(*r.top_by_replay[i - 1].replay_ns, *r.top_by_replay[i].replay_ns);
    uint64_t max_replay = 0;
    for (uint64_t c = 0; c < 1000; ++c)
        max_replay = std::max<uint64_t>(max_replay, 1000 + (c * 7919) % 5000);
    EXPECT_EQ(*r.top_by_replay[0].replay_ns, max_replay);

    ASSERT_LE(r.timeline.size(), 8u);
    uint64_t commands = 0, ops = 0, replay = 0, expected_replay = 0;
    for (uint64_t c = 0; c < 1000; ++c) expected_replay += 1000 + (c * 7919) % 5000;
    for (std::size_t i = 0; i < r.timeline.size(); ++i) {
        commands += r.timeline[i].commands;
        ops += r.timeline[i].ops;
        replay += r.timeline[i].replay_ns;
        if (i) {
            EXPECT_EQ(r.timeline[i].first_ordinal, r.timeline[i - 1].last_ordinal + 1);
        }
    }
    EXPECT_EQ(commands, 1000u);
    EXPECT_EQ(ops, 4000u);
    EXPECT_EQ(replay, expected_replay);
    EXPECT_EQ(r.timeline.front().first_ordinal, 0u);
    EXPECT_EQ(r.timeline.back().last_ordinal, 999u);

    EXPECT_EQ(r.regions, 40u);
    EXPECT_EQ(r.region_uses, 2000u);
    EXPECT_EQ(r.region_uses_not_tracked, 2000u - 40u);

    // Each command after the first submission takes the implicit data and scratch slots of the
    // command 4 before it: two overlap events per command from command 4 on.
    EXPECT_EQ(r.overlap_events, 2u * (1000u - 4u));
    // 10 pairs, plus the pairs of the 3 listed hazards found after the list was full.
    EXPECT_EQ(r.overlaps.size(), 13u);
    EXPECT_EQ(r.overlap_events_not_listed, r.overlap_events - 13u);
    uint64_t hazard_pairs = 0;
    for (const OverlapRow& o : r.overlaps) hazard_pairs += o.hazard;
    EXPECT_EQ(hazard_pairs, 3u);
    // Hazards every 64th command from 64 on, each matching the scratch overlap it names.
    EXPECT_EQ(r.hazards_total, 15u);  // 64, 128, ..., 960
    EXPECT_EQ(r.hazards.size(), 3u);
    EXPECT_EQ(r.hazards_not_listed, 12u);
    EXPECT_EQ(r.overlap_hazard_events, 15u);
    for (const HazardRow& h : r.hazards) EXPECT_EQ(h.matched_overlaps, 1u);
}

TEST(AnalyzerLimits, TimelineKeepsOneCommandPerBucketWhenItFits) {
    AnalyzerLimits limits;
    limits.timeline_buckets = 8;
    Analyzer a("timeline", limits);
    synthetic::StreamShape shape;
    shape.commands = 8;
    shape.ops_per_command = 1;
    synthetic::feed_stream(a, shape);
    AnalysisReport r = a.finish();
    ASSERT_EQ(r.timeline.size(), 8u);
    for (std::size_t i = 0; i < 8; ++i) {
        EXPECT_EQ(r.timeline[i].commands, 1u);
        EXPECT_EQ(r.timeline[i].first_ordinal, i);
        EXPECT_EQ(r.timeline[i].replay_ns, 1000 + (i * 7919) % 5000);
    }
}

TEST(AnalyzerLimits, TimelineHalvesResolutionWhenFull) {
    AnalyzerLimits limits;
    limits.timeline_buckets = 4;
    Analyzer a("timeline", limits);
    synthetic::StreamShape shape;
    shape.commands = 9;  // 9 > 4 -> width 2 (5 buckets > 4) -> width 4: buckets of 4, 4, 1
    shape.ops_per_command = 1;
    synthetic::feed_stream(a, shape);
    AnalysisReport r = a.finish();
    ASSERT_EQ(r.timeline.size(), 3u);
    EXPECT_EQ(r.timeline[0].commands, 4u);
    EXPECT_EQ(r.timeline[1].commands, 4u);
    EXPECT_EQ(r.timeline[2].commands, 1u);
    EXPECT_EQ(r.timeline[2].first_ordinal, 8u);
}

TEST(AnalyzerLimits, ZeroTimelineBucketsMeansOne) {
    AnalyzerLimits limits;
    limits.timeline_buckets = 0;
    Analyzer a("timeline", limits);
    synthetic::StreamShape shape;
    shape.commands = 100;
    shape.ops_per_command = 1;
    synthetic::feed_stream(a, shape);
    AnalysisReport r = a.finish();
    ASSERT_EQ(r.timeline.size(), 1u);
    EXPECT_EQ(r.timeline[0].commands, 100u);
    EXPECT_EQ(r.timeline[0].last_ordinal, 99u);
}

TEST(AnalyzerLimits, AnalyzerWithoutEventsGivesAnEmptyReport) {
    Analyzer a("empty");
    AnalysisReport r = a.finish();
    EXPECT_EQ(r.commands, 0u);
    EXPECT_TRUE(r.timeline.empty());
    EXPECT_TRUE(r.region_rows.empty());
}

}  // namespace
}  // namespace clastrace::analyze
