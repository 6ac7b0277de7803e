// SPDX-License-Identifier: Apache-2.0
// Golden tests of the streaming analysis on generated traces (analyze_scene.h) whose numbers
// are known: object sizes from the engine run by the writer, driver sizes = engine + 128,
// build-sizes answers, buffer sizes, timestamps 2 ns per tick, one scratch reused as implicit
// data (a safe reuse with a barrier, a WRITE-AFTER-WRITE hazard without), a legacy NV build and
// a deserialization. Checked in the report, the text, the JSON.
#include "analyze_scene.h"
#include "trace_files.h"

#include <clastrace/analyze/render.h>
#include <clastrace/analyze/replay_stream.h>
#include <clastrace/traces/trace_reader.h>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <numeric>
#include <sstream>
#include <unistd.h>

namespace clastrace {
namespace {

using S = test::AnalyzeScene;

std::string temp_path(const std::string& name) {
    return test::temp_trace_path("analyze_golden", name);
}

uint64_t sum(const std::vector<uint64_t>& v) {
    return std::accumulate(v.begin(), v.end(), uint64_t{0});
}

// Submission 0: ts 1000 | A: 3 clusters (2, 8, 18 triangles) | ts 1600 | [barrier] | B: 2
// clusters of 4 triangles at truncate bits 8, implicit data on A's scratch | ts 2600 | copy,
// NV build (24 indices), deserialization (256 bytes into a 4096-byte object) | ts 3100.
// Submission 1: C = A again. Calibration: tick 1000 = host 5 ms.
struct GoldenScene {
    bool barrier = true;
    test::BuiltClusters a, b, b_untruncated;
    traces::TraceWriterStats writer;
    analyze::TraceAnalysis analysis;

    explicit GoldenScene(bool with_barrier) : barrier(with_barrier) {
        const std::string path = temp_path(with_barrier ? "ordered.clt" : "hazard.clt");
        {
            test::AnalyzeSceneWriter w(path, 2.0f);
            w.timestamp(1000);
            test::ClusterBuild ba;
            ba.triangle_counts = {2, 8, 18};
            a = w.build(ba);
            w.timestamp(1600);
            if (barrier) w.build_to_build_barrier();
            test::ClusterBuild bb;
            bb.triangle_counts = {4, 4};
            bb.truncate_bits = 8;
            bb.dst = S::kPool + 0x20000;  // A's scratch
            bb.scratch = S::kPool + 0x30000;
            bb.arrays = S::kArrays + 0x400;
            bb.query_answer = 0x8000;
            b = w.build(bb);
            w.timestamp(2600);
            w.copy_buffer();
            w.nv_build(24, 12345, 2048);
            w.deserialize(256, 4096);
            w.timestamp(3100);
            w.submit();
            w.build(ba);  // C
            w.calibrate(1000, 5'000'000, 250);
            w.submit();
            writer = w.finish();
        }
        {
            // The same B clusters at truncate bits 0: what truncation saves.
            test::AnalyzeSceneWriter w(path + ".untruncated", 2.0f);
            test::ClusterBuild bb;
            bb.triangle_counts = {4, 4};
            b_untruncated = w.build(bb);
            w.finish();
        }
        traces::TraceError e;
        auto reader = traces::TraceReader::open(path, &e);
        if (!reader) throw std::runtime_error(e.message);
        analysis = analyze::analyze_trace(*reader, "golden.clt");
        std::filesystem::remove(path);
        std::filesystem::remove(path + ".untruncated");
    }
    uint64_t ordinal_of_b() const { return barrier ? 4 : 3; }
    uint64_t engine_bytes() const { return 2 * sum(a.engine_sizes) + sum(b.engine_sizes); }
};

const GoldenScene& ordered() {
    static const GoldenScene scene(true);
    return scene;
}
const GoldenScene& unordered() {
    static const GoldenScene scene(false);
    return scene;
}

TEST(StreamGolden, SceneIsWhatTheTestsAssume) {
    const GoldenScene& g = ordered();
    ASSERT_EQ(g.a.engine_sizes.size(), 3u);
    ASSERT_EQ(g.b.engine_sizes.size(), 2u);
    EXPECT_EQ(g.a.triangles, 28u);
    EXPECT_EQ(g.a.vertices, 34u);
    EXPECT_EQ(g.a.scratch_used, 48u);     // 16 bytes per op (engine/build_sizes.h)
    EXPECT_GE(g.b.engine_sizes[0], 48u);  // C's scratch lands inside B's first object
    // The scene deserializes another driver's blob: the replay notes it as opaque (two notes,
    // not findings), and finds nothing.
    EXPECT_TRUE(g.analysis.replay.findings.empty());
    for (const auto& n : g.analysis.replay.notes)
        EXPECT_TRUE(n.rule == "CLASTRACE-replay-nv-opaque-object" ||
                    n.rule == "CLASTRACE-serialized-blob-from-another-driver")
            << n.format();
}

TEST(StreamGolden, Totals) {
    const analyze::AnalysisReport& r = ordered().analysis.report;
    EXPECT_EQ(r.schema_version, 2);
    EXPECT_EQ(r.commands, 7u);  // A, barrier, B, copy, NV build, deserialization, C
    EXPECT_EQ(r.submissions, 2u);
    EXPECT_EQ(r.ops, 3u + 2u + 0u + 1u + 1u + 3u);
    EXPECT_EQ(r.objects, 8u + 1u);  // 8 cluster objects and the NV build's bottom level
    EXPECT_EQ(r.triangles, 28u + 8u + 8u + 28u);
    EXPECT_EQ(r.largest_submission, 0u);
    EXPECT_EQ(r.largest_submission_commands, 6u);
    EXPECT_EQ(r.largest_submission_ops, 7u);
    EXPECT_EQ(unordered().analysis.report.commands, 6u);
}

TEST(StreamGolden, SizesByOpType) {
    const GoldenScene& g = ordered();
    const analyze::OpTypeSizes& t = g.analysis.report.sizes(analyze::OpType::kBuildTriangleCluster);
    EXPECT_EQ(t.commands, 3u);
    EXPECT_EQ(t.ops, 8u);
    EXPECT_EQ(t.objects, 8u);
    EXPECT_EQ(t.triangles, 64u);
    EXPECT_EQ(t.vertices, 34u + 12u + 34u);
    EXPECT_EQ(t.engine_bytes.sum(), g.engine_bytes());
    EXPECT_EQ(t.engine_bytes.count(), 8u);
    std::vector<uint64_t> all = g.a.engine_sizes;
    all.insert(all.end(), g.a.engine_sizes.begin(), g.a.engine_sizes.end());
    all.insert(all.end(), g.b.engine_sizes.begin(), g.b.engine_sizes.end());
    std::sort(all.begin(), all.end());
    EXPECT_EQ(t.engine_bytes.min(), all.front());
    EXPECT_EQ(t.engine_bytes.max(), all.back());
    EXPECT_EQ(t.engine_bytes.median(), all[3]);  // lower median of 8
    EXPECT_TRUE(t.engine_bytes.median_exact());
    // The scene's "driver" reports 128 bytes more per object.
    EXPECT_EQ(t.objects_with_driver_bytes, 8u);
    EXPECT_EQ(t.driver_bytes.sum(), g.engine_bytes() + 8 * 128);
    EXPECT_EQ(t.driver_bytes.min(), all.front() + 128);
    // Build sizes: A, B, C each came with a query; C matches A's by input.
    EXPECT_EQ(t.commands_with_query, 3u);
    EXPECT_EQ(t.worst_case_bytes, 0x10000u + 0x8000u + 0x10000u);
    EXPECT_EQ(t.actual_bytes_of_queried, g.engine_bytes());
    // dstImplicitData: from its address to the end of the 256 KiB pool; used = the engine's packing.
    EXPECT_EQ(t.implicit_allocated, S::kPoolSize + (S::kPoolSize - 0x20000) + S::kPoolSize);
    EXPECT_EQ(t.implicit_used, 2 * g.a.implicit_used + g.b.implicit_used);
    EXPECT_EQ(t.scratch_allocated,
              (S::kPoolSize - 0x20000) + (S::kPoolSize - 0x30000) + (S::kPoolSize - 0x20000));
    EXPECT_EQ(t.scratch_required, 3u * 0x1000u);
    EXPECT_EQ(t.scratch_used, 48u + 32u + 48u);
}

TEST(StreamGolden, TruncationMeasuredByRebuild) {
    const GoldenScene& g = ordered();
    const auto& rows = g.analysis.report.truncation;
    ASSERT_EQ(rows.size(), 2u);
    EXPECT_EQ(rows[0].truncate_bits, 0u);
    EXPECT_EQ(rows[0].objects, 6u);
    EXPECT_EQ(rows[0].objects_with_untruncated, 0u);  // nothing to rebuild at 0 bits
    EXPECT_EQ(rows[1].truncate_bits, 8u);
    EXPECT_EQ(rows[1].objects, 2u);
    EXPECT_EQ(rows[1].triangles, 8u);
    EXPECT_EQ(rows[1].engine_bytes, sum(g.b.engine_sizes));
    EXPECT_EQ(rows[1].objects_with_untruncated, 2u);
    EXPECT_EQ(rows[1].untruncated_bytes, sum(g.b_untruncated.engine_sizes));
    EXPECT_EQ(g.analysis.stream.untruncated_rebuilds, 2u);
}

TEST(StreamGolden, AllCommandKindsListed) {
    const analyze::AnalysisReport& r = ordered().analysis.report;
    std::map<std::string, analyze::CommandKindRow> kinds;
    for (const auto& k : r.command_kinds) kinds[k.name] = k;
    ASSERT_EQ(kinds.size(), 5u);
    const auto& clas = kinds.at("vkCmdBuildClusterAccelerationStructureIndirectNV");
    EXPECT_EQ(clas.commands, 3u);
    EXPECT_EQ(clas.ops, 8u);
    EXPECT_EQ(clas.objects, 8u);
    EXPECT_EQ(clas.engine_bytes, ordered().engine_bytes());
    EXPECT_EQ(clas.driver_bytes, ordered().engine_bytes() + 8 * 128);
    EXPECT_EQ(clas.replay_commands, 3u);
    EXPECT_EQ(clas.gpu_commands, 2u);  // A and B each alone between two timestamps
    EXPECT_EQ(clas.gpu_ns, 1200u + 2000u);
    const auto& nv = kinds.at("vkCmdBuildAccelerationStructureNV");
    EXPECT_EQ(nv.commands, 1u);
    EXPECT_EQ(nv.ops, 1u);               // one geometry
    EXPECT_EQ(nv.triangles, 8u);         // 24 indices
    EXPECT_EQ(nv.driver_bytes, 12345u);  // its memory requirement (OBJECT)
    const auto& deser = kinds.at("vkCmdCopyMemoryToAccelerationStructureKHR");
    EXPECT_EQ(deser.commands, 1u);
    EXPECT_EQ(deser.driver_bytes, 4096u);                       // the KHR object's create size
    EXPECT_EQ(kinds.at("vkCmdPipelineBarrier2").commands, 1u);  // the golden scene's v2 barrier
    EXPECT_EQ(kinds.at("vkCmdCopyBuffer").commands, 1u);
}

TEST(StreamGolden, GpuTimestampsAndCalibration) {
    const analyze::AnalysisReport& r = ordered().analysis.report;
    ASSERT_TRUE(r.gpu_clock);
    EXPECT_EQ(r.gpu_clock->timestamp_period_ns, 2.0);
    EXPECT_TRUE(r.gpu_clock->period_known);
    ASSERT_EQ(r.gpu_spans.size(), 3u);
    EXPECT_EQ(r.gpu_spans_total, 3u);
    EXPECT_EQ(r.gpu_spans_ns, 1200u + 2000u + 1000u);
    const auto& s = r.gpu_spans;
    EXPECT_EQ(s[0].span.first_ordinal, 1u);
    EXPECT_EQ(s[0].span.commands, 1u);
    EXPECT_EQ(s[0].span.gpu_ns, 1200u);
    EXPECT_EQ(s[1].span.first_ordinal, 3u);  // the barrier, then B
    EXPECT_EQ(s[1].span.last_ordinal, 4u);
    EXPECT_EQ(s[1].span.commands, 2u);
    EXPECT_EQ(s[1].span.gpu_ns, 2000u);
    EXPECT_EQ(s[2].span.commands, 3u);  // copy, NV build, deserialization: no single command's time
    EXPECT_EQ(s[2].span.ops, 2u);
    EXPECT_EQ(s[2].span.triangles, 8u);
    EXPECT_EQ(s[2].span.gpu_ns, 1000u);
    EXPECT_EQ(s[0].start_ns, 0u);
    EXPECT_EQ(s[1].start_ns, 1200u);
    EXPECT_EQ(s[2].start_ns, 3200u);
    EXPECT_EQ(s[0].host_start_ns, 5'000'000u);
    EXPECT_EQ(s[2].host_start_ns, 5'003'200u);
    // Per command: A and B alone in their spans.
    std::map<uint64_t, analyze::CommandRow> rows;
    for (const auto& c : r.commands_listed) rows[c.ordinal] = c;
    EXPECT_EQ(rows.at(1).gpu_ns, 1200u);
    EXPECT_EQ(rows.at(4).gpu_ns, 2000u);
    EXPECT_FALSE(rows.at(7).gpu_ns);
    EXPECT_FALSE(rows.at(10).gpu_ns);  // C had no timestamps
    ASSERT_FALSE(r.top_by_gpu.empty());
    EXPECT_EQ(r.top_by_gpu[0].ordinal, 4u);
    EXPECT_TRUE(rows.at(1).replay_ns);  // engine time
}

TEST(StreamGolden, TraceBytesFromTheWriter) {
    const GoldenScene& g = ordered();
    ASSERT_TRUE(g.analysis.report.trace_bytes);
    const analyze::TraceBytes& t = *g.analysis.report.trace_bytes;
    EXPECT_EQ(t.deduplicated, g.writer.raw_bytes);
    EXPECT_EQ(t.compressed, g.writer.compressed_bytes);
    EXPECT_EQ(t.raw, g.writer.raw_bytes + g.writer.contents_bytes_deduplicated);
    EXPECT_GT(g.writer.contents_bytes_deduplicated, 0u);  // C's inputs repeat A's
}

TEST(StreamGolden, OrderedReuseIsSafe) {
    const analyze::AnalysisReport& r = ordered().analysis.report;
    EXPECT_EQ(r.hazards_total, 0u);
    // (1) B's implicit data takes A's 48 scratch bytes: reuse. (2) C (A's scratch region again)
    // takes them back from B's first object: aliasing (the scratch region was in use before).
    // Rebuilding A's dstImplicitData over A's own objects is no overlap.
    ASSERT_EQ(r.overlap_events, 2u) << analyze::render_text(r);
    EXPECT_EQ(r.overlap_hazard_events, 0u);
    ASSERT_EQ(r.overlaps.size(), 2u);
    const analyze::OverlapRow& first = r.overlaps[0];
    EXPECT_EQ(first.older_role, analyze::RegionRole::kScratch);
    EXPECT_EQ(first.newer_role, analyze::RegionRole::kImplicitData);
    EXPECT_EQ(first.older_command, 1u);
    EXPECT_EQ(first.newer_command, 4u);
    EXPECT_EQ(first.base, S::kPool + 0x20000);
    EXPECT_EQ(first.size, 48u);
    EXPECT_EQ(first.kind, analyze::OverlapKind::kReuse);
    EXPECT_FALSE(first.hazard);
    const analyze::OverlapRow& second = r.overlaps[1];
    EXPECT_EQ(second.older_role, analyze::RegionRole::kObjectClas);
    EXPECT_EQ(second.newer_role, analyze::RegionRole::kScratch);
    EXPECT_EQ(second.older_command, 4u);
    EXPECT_EQ(second.newer_command, 10u);
    EXPECT_EQ(second.size, 48u);
    EXPECT_EQ(second.kind, analyze::OverlapKind::kAliasing);
    // Regions with roles and lifetimes: A's scratch lives from A to C.
    bool found = false;
    for (const auto& row : r.region_rows)
        if (row.role == analyze::RegionRole::kScratch && row.base == S::kPool + 0x20000) {
            found = true;
            EXPECT_EQ(row.first_command, 1u);
            EXPECT_EQ(row.last_command, 10u);
            EXPECT_EQ(row.uses, 2u);
        }
    EXPECT_TRUE(found);
    std::set<analyze::RegionRole> roles;
    for (const auto& row : r.region_rows) roles.insert(row.role);
    for (analyze::RegionRole role :
         {analyze::RegionRole::kBuffer, analyze::RegionRole::kScratch,
          analyze::RegionRole::kImplicitData, analyze::RegionRole::kDstAddresses,
          analyze::RegionRole::kDstSizes, analyze::RegionRole::kSrcInfos,
          analyze::RegionRole::kObjectClas, analyze::RegionRole::kObjectBlas,
          analyze::RegionRole::kVertex, analyze::RegionRole::kIndex})
        EXPECT_TRUE(roles.count(role)) << analyze::region_role_name(role);
}

TEST(StreamGolden, MissingBarrierIsAHazardOnTheReusedBytes) {
    const analyze::AnalysisReport& r = unordered().analysis.report;
    ASSERT_EQ(r.hazards_total, 1u) << analyze::render_text(r);
    const analyze::HazardSummary& h = r.hazards[0].hazard;
    EXPECT_EQ(h.hazard_class, "WRITE-AFTER-WRITE");
    EXPECT_EQ(h.first_command, 1u);
    EXPECT_EQ(h.second_command, 3u);
    EXPECT_EQ(h.base, S::kPool + 0x20000);
    EXPECT_EQ(r.hazards[0].matched_overlaps, 1u);
    EXPECT_EQ(r.overlap_events, 2u);
    EXPECT_EQ(r.overlap_hazard_events, 1u);
    ASSERT_FALSE(r.overlaps.empty());
    EXPECT_TRUE(r.overlaps[0].hazard);
    EXPECT_EQ(r.overlaps[0].hazard_index, 0u);
}

TEST(StreamGolden, TextShowsTheNumbers) {
    const GoldenScene& g = ordered();
    const std::string text = analyze::render_text(g.analysis.report);
    std::istringstream lines(text);
    for (std::string line; std::getline(lines, line);)
        EXPECT_LE(line.size(), analyze::kTextColumns) << line;
    EXPECT_NE(text.find("largest submission: #0, 6 commands, 7 ops"), std::string::npos) << text;
    EXPECT_NE(text.find(
                  "GPU timestamp spans: 3 spans, 0.004 ms, 7 ops (1666667 ops/s), 44 triangles"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("calibrated: tick 1000 = host 5000000 ns +- 250 ns"), std::string::npos)
        << text;
    EXPECT_NE(text.find("\nCopyMemoryToAccelerationStructureKHR "), std::string::npos) << text;
    EXPECT_NE(text.find("\nBuildAccelerationStructureNV "), std::string::npos) << text;
    EXPECT_NE(text.find("\nBuildClusterAccelerationStructureIndirectNV "), std::string::npos)
        << text;
    // The sizes row of build_triangle_cluster: commands, ops, objects, triangles, bytes.
    const std::size_t sizes = text.find("Sizes by op type");
    ASSERT_NE(sizes, std::string::npos);
    std::istringstream row(text.substr(text.find("\nclas ", sizes) + 1));
    std::vector<std::string> cells(6);
    for (std::string& c : cells) row >> c;
    EXPECT_EQ(cells, (std::vector<std::string>{"clas", "3", "8", "8", "64",
                                               std::to_string(g.engine_bytes())}));
}

TEST(StreamGolden, JsonHoldsTheNumbers) {
    const GoldenScene& g = ordered();
    const nlohmann::json j = nlohmann::json::parse(analyze::render_json(g.analysis.report));
    EXPECT_EQ(j["schema_version"], 2);
    EXPECT_EQ(j["totals"]["largest_submission"]["ops"], 7);
    const nlohmann::json* clas = nullptr;
    for (const auto& t : j["sizes"]["by_op_type"])
        if (t["op_type"] == "build_triangle_cluster") clas = &t;
    ASSERT_NE(clas, nullptr);
    EXPECT_EQ((*clas)["engine_bytes"]["sum"], g.engine_bytes());
    EXPECT_EQ((*clas)["driver_bytes"]["sum"], g.engine_bytes() + 8 * 128);
    EXPECT_EQ((*clas)["build_sizes"]["worst_case_bytes"], 0x28000);
    EXPECT_EQ((*clas)["build_sizes"]["slack_bytes"], int64_t(0x28000) - int64_t(g.engine_bytes()));
    EXPECT_EQ((*clas)["scratch"]["used"], 128);
    EXPECT_DOUBLE_EQ((*clas)["bytes_per_vertex"].get<double>(), double(g.engine_bytes()) / 80.0);
    EXPECT_DOUBLE_EQ((*clas)["bytes_per_triangle"].get<double>(), double(g.engine_bytes()) / 64.0);
    EXPECT_EQ(j["timing"]["gpu_spans"]["gpu_ns"], 4200);
    EXPECT_EQ(j["timing"]["gpu_spans"]["listed"][2]["host_start_ns"], 5'003'200);
    EXPECT_EQ(j["timing"]["gpu_clock"]["calibration"]["max_deviation_ns"], 250);
    EXPECT_EQ(j["sizes"]["trace_bytes"]["compressed"], g.writer.compressed_bytes);
    EXPECT_EQ(j["overlap"]["events"], 2);
    bool nv = false;
    for (const auto& k : j["commands"]["kinds"])
        if (k["name"] == "vkCmdBuildAccelerationStructureNV") {
            nv = true;
            EXPECT_EQ(k["driver_bytes"], 12345);
            EXPECT_EQ(k["triangles"], 8);
        }
    EXPECT_TRUE(nv);
}

// Op modes: explicit destinations (objects where dstAddressesArray says, worst case = the
// per-object answer x ops, no implicit data) and compute sizes (sizes only, the captured
// dstSizesArray as driver sizes, nothing compared against a worst case).
TEST(StreamGolden, ExplicitAndComputeSizesModes) {
    const std::string path = temp_path("modes.clt");
    test::BuiltClusters ex, sizes;
    {
        test::AnalyzeSceneWriter w(path, 1.0f);
        test::ClusterBuild e;
        e.triangle_counts = {2, 8, 18};
        e.mode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
        e.dst = S::kPool + 0x10000;
        e.query_answer = 0x400;  // explicit: per object
        ex = w.build(e);
        w.build_to_build_barrier();
        test::ClusterBuild c;
        c.triangle_counts = {4, 4};
        c.mode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
        c.arrays = S::kArrays + 0x400;
        c.query = false;
        sizes = w.build(c);
        w.submit();
        w.finish();
    }
    traces::TraceError err;
    auto reader = traces::TraceReader::open(path, &err);
    ASSERT_TRUE(reader) << err.message;
    const analyze::TraceAnalysis a = analyze::analyze_trace(*reader, path);
    std::filesystem::remove(path);
    EXPECT_TRUE(a.replay.findings.empty()) << a.replay.findings[0].format();
    const analyze::AnalysisReport& r = a.report;
    const analyze::OpTypeSizes& t = r.sizes(analyze::OpType::kBuildTriangleCluster);
    EXPECT_EQ(t.commands, 2u);
    EXPECT_EQ(t.objects, 5u);
    EXPECT_EQ(t.engine_bytes.sum(), sum(ex.engine_sizes) + sum(sizes.engine_sizes));
    EXPECT_EQ(t.commands_with_query, 1u);
    EXPECT_EQ(t.worst_case_bytes, 3u * 0x400u);
    EXPECT_EQ(t.actual_bytes_of_queried, sum(ex.engine_sizes));
    EXPECT_EQ(t.objects_with_driver_bytes, 2u);
    EXPECT_EQ(t.driver_bytes.sum(), sum(sizes.engine_sizes) + 2 * 128);
    EXPECT_EQ(t.implicit_allocated, 0u);
    EXPECT_EQ(t.implicit_used, 0u);
    ASSERT_GE(r.commands_listed.size(), 3u);
    EXPECT_EQ(r.commands_listed[0].op_mode, analyze::OpMode::kExplicitDestinations);
    EXPECT_EQ(r.commands_listed[0].worst_case_bytes, 3u * 0x400u);
    EXPECT_EQ(r.commands_listed[2].op_mode, analyze::OpMode::kComputeSizes);
    EXPECT_FALSE(r.commands_listed[2].worst_case_bytes);
    int objects_at_slots = 0;
    for (const auto& row : r.region_rows) {
        EXPECT_NE(row.role, analyze::RegionRole::kImplicitData);
        if (row.role == analyze::RegionRole::kObjectClas) {
            EXPECT_EQ((row.base - (S::kPool + 0x10000)) % 1024, 0u);
            ++objects_at_slots;
        }
    }
    EXPECT_EQ(objects_at_slots, 3);
}

// Hostile clocks: a timestamp earlier than the one before it measures nothing (a note says so),
// and a header without timestampPeriod gets 1 ns per tick, said in a note.
TEST(StreamGolden, BackwardTimestampsAndMissingPeriodAreNotes) {
    const std::string path = temp_path("clock.clt");
    {
        test::AnalyzeSceneWriter w(path, 0.0f);
        test::ClusterBuild b;
        b.triangle_counts = {3};
        w.timestamp(5000);
        w.build(b);
        w.timestamp(1000);
        w.build(b);
        w.timestamp(1400);
        w.submit();
        w.finish();
    }
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    const analyze::TraceAnalysis a = analyze::analyze_trace(*reader, path);
    std::filesystem::remove(path);
    const analyze::AnalysisReport& r = a.report;
    ASSERT_EQ(r.gpu_spans_total, 1u);  // only 1000 -> 1400 is a span
    EXPECT_EQ(r.gpu_spans[0].span.gpu_ns, 400u);
    EXPECT_EQ(r.gpu_spans[0].span.first_ordinal, 3u);
    ASSERT_TRUE(r.gpu_clock);
    EXPECT_FALSE(r.gpu_clock->period_known);
    EXPECT_EQ(r.gpu_clock->timestamp_period_ns, 1.0);
    bool backwards = false, assumed = false;
    for (const std::string& n : r.notes) {
        backwards |= n.find("1 GPU timestamps are earlier than the timestamp before them") !=
                     std::string::npos;
        assumed |= n.find("no timestampPeriod: 1 ns per tick assumed") != std::string::npos;
    }
    EXPECT_TRUE(backwards);
    EXPECT_TRUE(assumed);
    const std::string text = analyze::render_text(r);
    EXPECT_NE(text.find("\nNotes\n"), std::string::npos);
    std::istringstream lines(text);
    for (std::string line; std::getline(lines, line);)
        EXPECT_LE(line.size(), analyze::kTextColumns) << line;
}

// Peak memory follows the largest submission: the feeder holds one submission's events, so
// a trace of many equal submissions holds exactly as many events at its peak as one of them.
TEST(StreamGolden, HeldEventsFollowTheLargestSubmission) {
    auto peak_events = [](int submissions, int extra_in_last) {
        const std::string path = temp_path("peak.clt");
        {
            test::AnalyzeSceneWriter w(path, 1.0f);
            test::ClusterBuild b;
            b.triangle_counts = {3, 3, 3, 3};
            for (int s = 0; s < submissions; ++s) {
                w.build(b);
                if (s == submissions - 1)
                    for (int k = 0; k < extra_in_last; ++k) w.build(b);
                w.submit();
            }
            w.finish();
        }
        traces::TraceError e;
        auto reader = traces::TraceReader::open(path, &e);
        const analyze::TraceAnalysis a = analyze::analyze_trace(*reader, path);
        std::filesystem::remove(path);
        return a.stream.largest_submission_events;
    };
    const uint64_t one = peak_events(1, 0), three = peak_events(1, 2);
    EXPECT_GT(one, 0u);
    EXPECT_GT(three, 2 * one);  // three builds (and the hazards between them, no barriers)
    EXPECT_EQ(peak_events(40, 0), one);
    EXPECT_EQ(peak_events(40, 2), three);
}

}  // namespace
}  // namespace clastrace
