// SPDX-License-Identifier: Apache-2.0
// `clastrace analyze` on the shipped sample (text, JSON, HTML, exit codes) and the streaming
// feeder (analyze_trace) on a trace with a known hazard and on damaged traces.
#include "analyze_scene.h"
#include "scene_trace.h"
#include "trace_files.h"

#include <clastrace/analyze/analyzer.h>
#include <clastrace/analyze/render.h>
#include <clastrace/analyze/replay_stream.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <sstream>
#include <vector>
#include <string>
#include <sys/wait.h>
#include <unistd.h>

namespace clastrace {
namespace {

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr uint64_t kAsRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;

using test::damaged_copy;

std::string temp_path(const std::string& name) {
    return test::temp_trace_path("analyze_cli", name);
}

std::string read_file(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
}

int run_cli(const std::string& args, std::string* out) {
    const std::string out_path = temp_path("cli.out");
    const std::string cmd =
        std::string(CLASTRACE_BIN) + " " + args + " > " + out_path + " 2>/dev/null";
    int status = std::system(cmd.c_str());
    *out = read_file(out_path);
    std::remove(out_path.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// Two builds sharing scratchData; without the barrier the second one is a WRITE-AFTER-WRITE.
void scratch_scene(const std::string& path, bool with_barrier) {
    test::SceneTrace t(path, true);
    t.build({});
    if (with_barrier) t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
    test::BuildCall second;
    second.dst = test::SceneBuffers::kDst2;
    second.addresses = test::SceneBuffers::kAddresses2;
    second.sizes = test::SceneBuffers::kSizes2;
    second.first_cluster_id = 200;
    t.build(second);
    t.finish();
}

TEST(AnalyzeCli, TextHasSizeTables) {
    std::string out;
    ASSERT_EQ(run_cli(std::string("analyze ") + CLASTRACE_SAMPLE, &out), 0) << out;
    EXPECT_NE(out.find("Sizes by op type (engine bytes per object)"), std::string::npos) << out;
    EXPECT_NE(out.find("Driver sizes (objects whose dstSizesArray was captured)"),
              std::string::npos)
        << out;
}

TEST(AnalyzeCli, JsonCountsMatchReplay) {
    std::string replay_out, analyze_out;
    ASSERT_EQ(run_cli(std::string("replay --json ") + CLASTRACE_SAMPLE, &replay_out), 0)
        << replay_out;
    ASSERT_EQ(run_cli(std::string("analyze --json ") + CLASTRACE_SAMPLE, &analyze_out), 0)
        << analyze_out;
    const nlohmann::json r = nlohmann::json::parse(replay_out);
    const nlohmann::json a = nlohmann::json::parse(analyze_out);
    EXPECT_EQ(a["schema_version"], 2);
    // Every replayed command is fed (timestamps and labels are spans, not commands).
    ASSERT_GT(r["counts"]["cluster_commands"].get<uint64_t>(), 0u);
    EXPECT_EQ(a["totals"]["commands"], r["counts"]["commands"]);
    uint64_t cluster_commands = 0, cluster_ops = 0;
    for (const auto& k : a["commands"]["kinds"])
        if (k["name"] == "vkCmdBuildClusterAccelerationStructureIndirectNV") {
            cluster_commands = k["commands"].get<uint64_t>();
            cluster_ops = k["ops"].get<uint64_t>();
        }
    EXPECT_EQ(cluster_commands, r["counts"]["cluster_commands"]);
    EXPECT_EQ(cluster_ops, r["counts"]["cluster_ops"]);
    uint64_t compared_ops = 0, engine_bytes = 0, captured_bytes = 0;
    for (const auto& s : r["sizes"]) {
        compared_ops += s["first_ops"].size();
        for (const auto& op : s["first_ops"]) {
            engine_bytes += op["engine"].get<uint64_t>();
            captured_bytes += op["captured"].get<uint64_t>();
        }
    }
    // The sample also builds one NV bottom level (replay rebuilds it: one more object, under
    // "other"); the cluster objects are the ones replay compared.
    uint64_t nv_objects = 0;
    for (const auto& k : a["commands"]["kinds"])
        if (k["name"] == "vkCmdBuildAccelerationStructureNV")
            nv_objects = k["objects"].get<uint64_t>();
    EXPECT_EQ(nv_objects, r["counts"]["nv_builds"]);
    EXPECT_EQ(a["totals"]["objects"],
              compared_ops + nv_objects);  // the sample has < 64 ops per command
    uint64_t objects = 0, engine = 0, driver = 0;
    for (const auto& t : a["sizes"]["by_op_type"]) {
        if (t["op_type"] == "other") continue;  // the NV object
        objects += t["objects"].get<uint64_t>();
        engine += t["engine_bytes"]["sum"].get<uint64_t>();
        if (!t["driver_bytes"].is_null()) driver += t["driver_bytes"]["sum"].get<uint64_t>();
    }
    EXPECT_EQ(objects, compared_ops);
    EXPECT_EQ(engine, engine_bytes);
    EXPECT_EQ(driver, captured_bytes);
    EXPECT_EQ(a["hazards"]["total"], 0);
    // The sample brackets its commands with two GPU timestamps 48250 ticks apart.
    ASSERT_EQ(a["timing"]["gpu_spans"]["total"], 1);
    EXPECT_FALSE(a["sizes"]["trace_bytes"].is_null());
}

TEST(AnalyzeCli, HtmlIsSelfContainedWithSvg) {
    const std::string html_path = temp_path("report.html");
    std::string out;
    ASSERT_EQ(run_cli(std::string("analyze ") + CLASTRACE_SAMPLE + " --html " + html_path, &out), 0)
        << out;
    EXPECT_NE(out.find(html_path), std::string::npos) << out;  // says where the report is
    const std::string html = read_file(html_path);
    EXPECT_EQ(html.rfind("<!DOCTYPE html>", 0), 0u) << html.substr(0, 80);
    EXPECT_NE(html.find("<svg"), std::string::npos);
    EXPECT_EQ(html.find("<script"), std::string::npos);
    EXPECT_EQ(html.find("http://"),
              html.find("http://www.w3.org/2000/svg"));  // only the SVG namespace
    EXPECT_EQ(html.find("https://"), std::string::npos);
    std::remove(html_path.c_str());
}

TEST(AnalyzeCli, ExitCodes) {
    std::string out;
    EXPECT_EQ(run_cli("analyze /nonexistent/trace.clt", &out), 2);
    EXPECT_EQ(run_cli(std::string("analyze --json --html x.html ") + CLASTRACE_SAMPLE, &out), 2);
    EXPECT_EQ(run_cli("analyze", &out), 2);
    EXPECT_EQ(run_cli("analyze --help", &out), 0);
    EXPECT_NE(out.find("--truncation-rebuilds"), std::string::npos) << out;
    EXPECT_EQ(run_cli(std::string("analyze --truncation-rebuilds -1 ") + CLASTRACE_SAMPLE, &out),
              2);
    EXPECT_EQ(run_cli(std::string("analyze --truncation-rebuilds 0 --json ") + CLASTRACE_SAMPLE,
                      &out),
              0);
    EXPECT_EQ(run_cli(std::string("analyze ") + CLASTRACE_SAMPLE +
                          " --html /nonexistent-dir/r.html",
                      &out),
              2);

    const std::string hazard = temp_path("hazard.clt");
    scratch_scene(hazard, false);
    EXPECT_EQ(run_cli("analyze --json " + hazard, &out), 1);
    const nlohmann::json a = nlohmann::json::parse(out);
    EXPECT_EQ(a["hazards"]["total"], 1);
    scratch_scene(hazard, true);
    EXPECT_EQ(run_cli("analyze " + hazard, &out), 0) << out;
    std::remove(hazard.c_str());
}

TEST(AnalyzeTrace, HazardNamesBothBuildsInSequenceOrder) {
    const std::string path = temp_path("stream.clt");
    scratch_scene(path, false);
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    const analyze::TraceAnalysis a = analyze::analyze_trace(*reader, path);
    std::remove(path.c_str());

    const replay::ReplayReport& r = a.replay;
    ASSERT_EQ(r.sizes.size(), 2u);
    ASSERT_EQ(r.hazards.size(), 1u);
    EXPECT_EQ(a.report.commands, r.counts.commands);
    EXPECT_EQ(a.report.objects, r.counts.cluster_ops);
    ASSERT_EQ(a.report.hazards.size(), 1u);
    const analyze::HazardSummary& h = a.report.hazards[0].hazard;
    EXPECT_EQ(h.hazard_class, "WRITE-AFTER-WRITE");
    EXPECT_EQ(h.first_command, r.sizes[0].where.sequence);
    EXPECT_EQ(h.second_command, r.sizes[1].where.sequence);
    EXPECT_GT(h.size, 0u);
    const analyze::OpTypeSizes& clas = a.report.sizes(analyze::OpType::kBuildTriangleCluster);
    EXPECT_EQ(clas.commands, 2u);
    EXPECT_EQ(clas.objects_with_driver_bytes, r.counts.cluster_ops);
    uint64_t engine = 0;
    for (const auto& s : r.sizes) engine += s.engine_bytes;
    EXPECT_EQ(clas.engine_bytes.sum(), engine);
    // Both builds write the same scratch bytes: one region, so the hazard has no overlap event
    // of two regions; it is still listed with both commands.
    EXPECT_EQ(a.report.hazards_total, 1u);
}

// A BLAS over a built CLAS, then a move of that CLAS into the BLAS's memory: the CLAS is one
// region from its build through both reads; the move's implicit data taking the BLAS's bytes
// is an ordered reuse, and so is the BLAS's 16-byte scratch on the first build's 32.
TEST(AnalyzeTrace, BlasAndMoveReadTheClasTheyName) {
    const std::string path = temp_path("blas_move.clt");
    {
        test::SceneTrace t(path, true);
        t.build({});
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.build_blas({test::SceneBuffers::kDst});
        t.barrier(kBuild, kAsWrite, kBuild, kAsRead | kAsWrite);
        t.move_clusters({test::SceneBuffers::kDst});
        t.finish();
    }
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    ASSERT_TRUE(reader) << e.message;
    const analyze::TraceAnalysis a = analyze::analyze_trace(*reader, path);
    std::remove(path.c_str());
    const analyze::AnalysisReport& r = a.report;
    EXPECT_EQ(r.hazards_total, 0u);
    EXPECT_EQ(r.sizes(analyze::OpType::kBuildClustersBottomLevel).objects, 1u);
    EXPECT_EQ(r.sizes(analyze::OpType::kMoveObjects).objects, 1u);
    const analyze::RegionRow* clas = nullptr;
    for (const auto& row : r.region_rows)
        if (row.role == analyze::RegionRole::kObjectClas && row.base == test::SceneBuffers::kDst)
            clas = &row;
    ASSERT_NE(clas, nullptr);
    EXPECT_EQ(clas->first_command, 0u);
    EXPECT_EQ(clas->last_command, 4u);  // build 0, barrier 1, BLAS 2, barrier 3, move 4
    EXPECT_EQ(clas->uses, 3u);
    ASSERT_EQ(r.overlap_events, 2u) << analyze::render_text(r);
    EXPECT_EQ(r.overlaps[0].older_role, analyze::RegionRole::kScratch);
    EXPECT_EQ(r.overlaps[0].size, 16u);
    EXPECT_EQ(r.overlaps[1].older_role, analyze::RegionRole::kObjectBlas);
    EXPECT_EQ(r.overlaps[1].older_command, 2u);
    EXPECT_EQ(r.overlaps[1].newer_role, analyze::RegionRole::kImplicitData);
    EXPECT_EQ(r.overlaps[1].newer_command, 4u);
    for (const auto& o : r.overlaps) {
        EXPECT_EQ(o.kind, analyze::OverlapKind::kReuse);
        EXPECT_FALSE(o.hazard);
    }
}

// Damaged traces replay with gaps (commands cut off, hazards without their first command):
// the feeder must still hand the analyzer a valid event stream.
// A scene with every record kind the feeder reads: timestamps, calibration, build-sizes
// queries, an NV build and a deserialization.
void every_kind_scene(const std::string& path) {
    test::AnalyzeSceneWriter w(path, 2.0f);
    w.timestamp(1000);
    test::ClusterBuild a;
    a.triangle_counts = {2, 8, 18};
    a.truncate_bits = 6;
    w.build(a);
    w.timestamp(1600);
    w.nv_build(24, 12345, 2048);
    w.deserialize(256, 4096);
    w.timestamp(3100);
    w.calibrate(1000, 5'000'000, 250);
    w.submit();
    w.build(a);
    w.submit();
    w.finish();
}

class AnalyzeDamaged : public ::testing::TestWithParam<int> {};

TEST_P(AnalyzeDamaged, StillFeedValidEvents) {
    const std::string clean = temp_path("mutate_clean.clt");
    if (GetParam() == 0)
        scratch_scene(clean, false);
    else
        every_kind_scene(clean);
    const std::string bytes_text = read_file(clean);
    const std::vector<char> bytes(bytes_text.begin(), bytes_text.end());
    ASSERT_GT(bytes.size(), 200u);
    std::mt19937_64 rng(7 + GetParam());
    const std::string path = temp_path("mutate.clt");
    int replayed = 0;
    for (int round = 0; round < 60; ++round) {
        const std::vector<char> mutant = damaged_copy(bytes, round, rng);
        std::ofstream(path, std::ios::binary).write(mutant.data(), std::streamsize(mutant.size()));
        traces::TraceError e;
        auto reader = traces::TraceReader::open(path, &e);
        if (!reader) continue;
        ++replayed;
        analyze::TraceAnalysis a;
        ASSERT_NO_THROW(a = analyze::analyze_trace(*reader, path)) << "round " << round;
        std::istringstream lines(analyze::render_text(a.report));
        for (std::string line; std::getline(lines, line);)
            EXPECT_LE(line.size(), analyze::kTextColumns) << line;
        EXPECT_TRUE(nlohmann::json::accept(analyze::render_json(a.report))) << "round " << round;
        EXPECT_NE(analyze::render_html(a.report).find("</html>"), std::string::npos);
        EXPECT_EQ(a.report.commands, a.replay.counts.commands + a.replay.counts.skipped_commands)
            << "round " << round;
        EXPECT_LE(a.report.hazards_total, a.stream.hazards);
    }
    EXPECT_GT(replayed, 0);
    std::remove(path.c_str());
    std::remove(clean.c_str());
}

INSTANTIATE_TEST_SUITE_P(Scenes, AnalyzeDamaged, ::testing::Values(0, 1));

}  // namespace
}  // namespace clastrace
