// SPDX-License-Identifier: Apache-2.0
// Golden tests: the synthetic scenario of synthetic_input.h, whose numbers are derived by
// hand in its comments, checked field by field in the report, the text and the JSON, plus
// one full golden text output.
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "clastrace/analyze/render.h"
#include "synthetic_input.h"

namespace clastrace::analyze {
namespace {

AnalysisReport small_report() {
    Analyzer a("small.clastrace");
    synthetic::feed_small_scenario(a);
    return a.finish();
}

TEST(AnalyzerGolden, Totals) {
    AnalysisReport r = small_report();
    EXPECT_EQ(r.commands, 3u);
    EXPECT_EQ(r.submissions, 2u);
    EXPECT_EQ(r.ops, 6u);
    EXPECT_EQ(r.objects, 6u);
    EXPECT_EQ(r.triangles, 160u);
    EXPECT_EQ(r.regions, 14u);
    EXPECT_EQ(r.region_uses, 18u);
}

TEST(AnalyzerGolden, SizesPerOpType) {
    AnalysisReport r = small_report();
    const OpTypeSizes& clas = r.sizes(OpType::kBuildTriangleCluster);
    EXPECT_EQ(clas.commands, 2u);
    EXPECT_EQ(clas.ops, 5u);
    EXPECT_EQ(clas.objects, 5u);
    EXPECT_EQ(clas.triangles, 100u);
    EXPECT_EQ(clas.vertices, 120u);
    EXPECT_EQ(clas.engine_bytes.sum(), 5500u);
    EXPECT_EQ(clas.engine_bytes.min(), 900u);
    EXPECT_EQ(clas.engine_bytes.median(), 1000u);
    EXPECT_EQ(clas.engine_bytes.max(), 1400u);
    EXPECT_EQ(clas.engine_bytes.log2_bins()[10], 3u);  // 512..1023: 1000, 900, 1000
    EXPECT_EQ(clas.engine_bytes.log2_bins()[11], 2u);  // 1200, 1400
    EXPECT_EQ(clas.objects_with_driver_bytes, 3u);
    EXPECT_EQ(clas.driver_bytes.sum(), 3900u);
    EXPECT_EQ(clas.driver_bytes.median(), 1300u);
    EXPECT_EQ(clas.engine_bytes_of_driver_objects, 3600u);
    EXPECT_EQ(clas.commands_with_query, 2u);
    EXPECT_EQ(clas.worst_case_bytes, 7400u);  // 5000 + 2400 (implicit: whole buffer)
    EXPECT_EQ(clas.actual_bytes_of_queried, 5500u);
    EXPECT_EQ(clas.implicit_allocated, 7000u);
    EXPECT_EQ(clas.implicit_used, 5500u);
    EXPECT_EQ(clas.scratch_allocated, 8192u);
    EXPECT_EQ(clas.scratch_required, 3072u);

    const OpTypeSizes& blas = r.sizes(OpType::kBuildClustersBottomLevel);
    EXPECT_EQ(blas.objects, 1u);
    EXPECT_EQ(blas.worst_case_bytes, 1000u);  // explicit: 1000 per object x 1 op
    EXPECT_EQ(blas.actual_bytes_of_queried, 800u);
    EXPECT_EQ(blas.implicit_allocated, 0u);
    EXPECT_EQ(blas.scratch_allocated, 4096u);
    EXPECT_EQ(blas.scratch_required, 512u);
}

TEST(AnalyzerGolden, TruncationAndTraceBytes) {
    AnalysisReport r = small_report();
    ASSERT_EQ(r.truncation.size(), 3u);
    EXPECT_EQ(r.truncation[0].truncate_bits, 0u);
    EXPECT_EQ(r.truncation[0].objects, 2u);
    EXPECT_EQ(r.truncation[0].engine_bytes, 2200u);
    EXPECT_EQ(r.truncation[1].truncate_bits, 4u);
    EXPECT_EQ(r.truncation[1].objects, 2u);
    EXPECT_EQ(r.truncation[1].triangles, 45u);
    EXPECT_EQ(r.truncation[1].objects_with_untruncated, 1u);
    EXPECT_EQ(r.truncation[1].engine_bytes_of_those, 900u);
    EXPECT_EQ(r.truncation[1].untruncated_bytes, 1000u);
    EXPECT_EQ(r.truncation[2].truncate_bits, 8u);
    EXPECT_EQ(r.truncation[2].untruncated_bytes, 1200u);
    ASSERT_TRUE(r.trace_bytes);
    EXPECT_EQ(r.trace_bytes->deduplicated, 40000u);
}

TEST(AnalyzerGolden, OverlapsAndHazards) {
    AnalysisReport r = small_report();
    EXPECT_EQ(r.overlap_events, 5u);
    EXPECT_EQ(r.overlap_hazard_events, 1u);
    ASSERT_EQ(r.overlaps.size(), 5u);
    auto find = [&](uint64_t older, uint64_t newer) -> const OverlapRow& {
        for (const OverlapRow& o : r.overlaps)
            if (o.older_region == older && o.newer_region == newer) return o;
        ADD_FAILURE() << "no overlap " << older << " -> " << newer;
        static OverlapRow none;
        return none;
    };
    const OverlapRow& scratch_reuse = find(11, 21);
    EXPECT_EQ(scratch_reuse.kind, OverlapKind::kReuse);
    EXPECT_FALSE(scratch_reuse.hazard);
    EXPECT_EQ(scratch_reuse.size, 4096u);
    EXPECT_EQ(scratch_reuse.older_command, 0u);
    EXPECT_EQ(scratch_reuse.newer_command, 1u);

    // Two reads of the same src infos bytes share them: no overlap.
    for (const OverlapRow& o : r.overlaps)
        EXPECT_FALSE(o.older_region == 12 && o.newer_region == 22);

    const OverlapRow& hazard = find(101, 30);
    EXPECT_TRUE(hazard.hazard);
    EXPECT_EQ(hazard.hazard_class, "WRITE_AFTER_READ");
    ASSERT_TRUE(hazard.hazard_index);
    EXPECT_EQ(*hazard.hazard_index, 0u);
    EXPECT_EQ(hazard.base, 0x10400u);
    EXPECT_EQ(hazard.size, 1200u);
    EXPECT_EQ(hazard.older_command, 1u);  // cmd 1 read clas 1 last
    EXPECT_EQ(hazard.older_label, "clas 1");
    EXPECT_EQ(hazard.newer_label, "implicit C");

    const OverlapRow& tail = find(10, 30);
    EXPECT_EQ(tail.base, 0x108b0u);
    EXPECT_EQ(tail.size, 80u);
    EXPECT_FALSE(tail.hazard);  // hazard names command 1, these bytes were last used by command 0

    const OverlapRow& neighbour = find(102, 30);
    EXPECT_EQ(neighbour.size, 720u);
    EXPECT_FALSE(neighbour.hazard);  // same commands as the hazard, but outside its range

    const OverlapRow& aliasing = find(21, 11);
    EXPECT_EQ(aliasing.kind, OverlapKind::kAliasing);  // scratch A is live before and after B
    EXPECT_FALSE(aliasing.hazard);

    // Objects inside their own command's implicit data are contained by design, not overlaps.
    for (const OverlapRow& o : r.overlaps) EXPECT_LT(o.newer_region, 300u);

    ASSERT_EQ(r.hazards.size(), 1u);
    EXPECT_EQ(r.hazards[0].matched_overlaps, 1u);
    EXPECT_EQ(r.hazards_total, 1u);
    ASSERT_EQ(r.commands_listed.size(), 3u);
    EXPECT_EQ(r.commands_listed[2].hazards, 1u);

    uint64_t summary_events = 0, summary_hazards = 0;
    for (const OverlapSummaryRow& s : r.overlap_summary) {
        summary_events += s.events;
        if (s.hazard) summary_hazards += s.events;
    }
    EXPECT_EQ(summary_events, 5u);
    EXPECT_EQ(summary_hazards, 1u);
}

TEST(AnalyzerGolden, RegionLifetimes) {
    AnalysisReport r = small_report();
    auto region = [&](uint64_t id) -> const RegionRow& {
        for (const RegionRow& g : r.region_rows)
            if (g.id == id) return g;
        ADD_FAILURE() << "no region " << id;
        static RegionRow none;
        return none;
    };
    EXPECT_EQ(region(11).first_command, 0u);
    EXPECT_EQ(region(11).last_command, 2u);
    EXPECT_EQ(region(11).uses, 2u);
    EXPECT_EQ(region(101).last_command, 1u);
    EXPECT_TRUE(region(101).written);
    EXPECT_FALSE(region(12).written);
    EXPECT_EQ(region(30).first_command, 2u);
}

TEST(AnalyzerGolden, Timing) {
    AnalysisReport r = small_report();
    EXPECT_TRUE(r.gpu_timing_present);
    const OpTypeSizes& clas = r.sizes(OpType::kBuildTriangleCluster);
    EXPECT_EQ(clas.replay_ns, 250000u);
    EXPECT_EQ(clas.replay_ops, 5u);
    EXPECT_EQ(clas.gpu_ns, 50000u);
    EXPECT_EQ(clas.gpu_commands, 1u);
    EXPECT_EQ(clas.gpu_ops, 3u);
    ASSERT_EQ(r.top_by_gpu.size(), 2u);  // command 2 has no GPU timestamp
    EXPECT_EQ(r.top_by_gpu[0].ordinal, 0u);
    EXPECT_EQ(r.top_by_gpu[1].ordinal, 1u);
    ASSERT_EQ(r.top_by_replay.size(), 3u);
    EXPECT_EQ(r.top_by_replay[0].ordinal, 0u);
    EXPECT_EQ(r.top_by_replay[2].ordinal, 2u);
    ASSERT_EQ(r.timeline.size(), 3u);
    EXPECT_EQ(r.timeline[1].gpu_ns, 20000u);
    EXPECT_EQ(r.timeline[2].replay_ns, 50000u);
}

TEST(AnalyzerGolden, TextShowsTheNumbers) {
    const std::string text = render_text(small_report());
    // Selected rows; spacing is the table's, so compare the whole row.
    EXPECT_NE(text.find("clas        2    5        5        100   5500  900    1000  1400  55.00"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("clas           2        7400    5500   1900   25.7%      7000  5500     "
                        "8192      3072"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("clas 1      object_clas      1  implicit C  implicit_data    2  0x10400   "
                        "1200  reuse     HAZARD #0"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("   8        1         25   1000  40.00           1200  16.7%"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("clas         0.250  20000    0.400         1   0.050  60000    1.200"),
              std::string::npos)
        << text;
}

TEST(AnalyzerGolden, FullTextMatchesGoldenFile) {
    const std::string text = render_text(small_report());
    std::ifstream in(std::string(CLASTRACE_ANALYZE_GOLDEN_DIR) + "/small.txt");
    ASSERT_TRUE(in) << "missing golden file small.txt";
    std::stringstream golden;
    golden << in.rdbuf();
    EXPECT_EQ(text, golden.str())
        << "text report changed; if intended, regenerate tests/analyze/golden/small.txt";
}

TEST(AnalyzerGolden, JsonFields) {
    const nlohmann::json j = nlohmann::json::parse(render_json(small_report()));
    EXPECT_EQ(j["schema_version"], 2);
    EXPECT_EQ(j["totals"]["commands"], 3);
    EXPECT_EQ(j["totals"]["triangles"], 160);
    const auto& by = j["sizes"]["by_op_type"];
    ASSERT_EQ(by.size(), 2u);
    EXPECT_EQ(by[0]["op_type"], "build_clusters_bottom_level");
    EXPECT_EQ(by[1]["op_type"], "build_triangle_cluster");
    EXPECT_EQ(by[1]["engine_bytes"]["median"], 1000);
    EXPECT_EQ(by[1]["engine_bytes"]["median_exact"], true);
    EXPECT_EQ(by[1]["engine_bytes"]["log2_histogram"][0]["low"], 512);
    EXPECT_EQ(by[1]["engine_bytes"]["log2_histogram"][0]["high"], 1023);
    EXPECT_EQ(by[1]["engine_bytes"]["log2_histogram"][0]["count"], 3);
    EXPECT_DOUBLE_EQ(by[1]["bytes_per_triangle"].get<double>(), 55.0);
    EXPECT_EQ(by[1]["build_sizes"]["slack_bytes"], 1900);
    EXPECT_NEAR(by[1]["build_sizes"]["slack_ratio"].get<double>(), 1900.0 / 7400.0, 1e-12);
    EXPECT_EQ(by[1]["implicit_data"]["allocated"], 7000);
    EXPECT_EQ(by[1]["scratch"]["required"], 3072);
    EXPECT_TRUE(by[0]["driver_bytes"].is_null());
    EXPECT_EQ(by[1]["driver_bytes"]["sum"], 3900);
    EXPECT_EQ(j["sizes"]["truncation"][1]["saved_ratio"], 0.1);
    EXPECT_EQ(j["sizes"]["trace_bytes"]["compression_ratio"], 10.0);
    EXPECT_EQ(j["overlap"]["events"], 5);
    EXPECT_EQ(j["overlap"]["hazard_events"], 1);
    EXPECT_EQ(j["overlap"]["pairs"][1]["older_region"], 101);
    EXPECT_EQ(j["overlap"]["pairs"][1]["hazard"], true);
    EXPECT_EQ(j["overlap"]["pairs"][1]["hazard_index"], 0);
    EXPECT_EQ(j["overlap"]["pairs"][4]["kind"], "aliasing");
    EXPECT_EQ(j["hazards"]["listed"][0]["class"], "WRITE_AFTER_READ");
    EXPECT_EQ(j["hazards"]["listed"][0]["first_command"], 1);
    EXPECT_EQ(j["commands"]["listed"][2]["gpu_ns"], nullptr);
    EXPECT_EQ(j["commands"]["listed"][1]["worst_case_bytes"], 1000);
    EXPECT_EQ(j["timing"]["by_op_type"][1]["replay_ops_per_second"], 20000.0);
    EXPECT_EQ(j["timing"]["top_by_gpu"].size(), 2u);
}

}  // namespace
}  // namespace clastrace::analyze
