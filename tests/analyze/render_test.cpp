// SPDX-License-Identifier: Apache-2.0
#include <fstream>
#include <set>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "clastrace/analyze/render.h"
#include "clastrace/analyze/report_output.h"
#include "svg_charts.h"
#include "synthetic_input.h"

namespace clastrace::analyze {
namespace {

AnalysisReport small_report() {
    Analyzer a("small.clastrace");
    synthetic::feed_small_scenario(a);
    return a.finish();
}

AnalysisReport stream_report(uint64_t commands) {
    Analyzer a("stream");
    synthetic::StreamShape shape;
    shape.commands = commands;
    shape.ops_per_command = 8;
    shape.with_object_regions = true;
    synthetic::feed_stream(a, shape);
    return a.finish();
}

std::size_t count(const std::string& s, const std::string& what) {
    std::size_t n = 0;
    for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + what.size())) ++n;
    return n;
}

void expect_lines_fit(const std::string& text) {
    std::istringstream lines(text);
    std::size_t n = 0;
    for (std::string line; std::getline(lines, line); ++n)
        EXPECT_LE(line.size(), kTextColumns)
            << "line " << n << " is " << line.size() << " wide: " << line;
    EXPECT_GT(n, 20u);
}

TEST(RenderText, EveryLineFitsA100ColumnTerminal) {
    expect_lines_fit(render_text(small_report()));
    expect_lines_fit(render_text(stream_report(700)));
}

TEST(RenderText, LongAndHostileStringsStayWithinWidthAndOnOneLine) {
    Analyzer a(std::string(500, 'T') + "\nsecond line");
    CommandInfo c;
    c.ordinal = 1;
    c.name = std::string(400, 'n') + "\n\t";
    c.op_type = OpType::kBuildTriangleCluster;
    c.op_count = UINT64_MAX;
    c.triangles = UINT64_MAX;
    c.replay_ns = UINT64_MAX;
    c.gpu_ns = 1;
    a.on_command(c);
    a.on_region(RegionInfo{1, std::string(300, 'L'), 0, 100, RegionRole::kSrcInfosCount, true});
    a.on_region(RegionInfo{2, "x\ny", 50, 100, RegionRole::kObjectTemplate, true});
    a.on_hazard(HazardSummary{std::string(200, 'C'), 1, 1, 0, 0,
                              "multi\nline\nmessage" + std::string(200, 'm')});
    ObjectInfo o;
    o.engine_bytes = UINT64_MAX;
    o.driver_bytes = UINT64_MAX;
    a.on_object(o);
    const std::string text = render_text(a.finish());
    expect_lines_fit(text);
    EXPECT_EQ(text.find("\nsecond line"),
              std::string::npos);  // the newline became '?', not a new line
    EXPECT_NE(text.find("?second line"), std::string::npos);
    EXPECT_EQ(text.find("\nmessage"), std::string::npos);
}

TEST(RenderJson, IsValidWithSchemaVersionEvenForInvalidUtf8) {
    Analyzer a("bad \xff\xfe utf8");
    CommandInfo c;
    c.name = "\xc3\x28";
    a.on_command(c);
    const nlohmann::json j = nlohmann::json::parse(render_json(a.finish()));
    EXPECT_EQ(j["schema_version"], kReportSchemaVersion);
    EXPECT_EQ(j["totals"]["commands"], 1);
    EXPECT_TRUE(j["sizes"]["trace_bytes"].is_null());
}

TEST(RenderJson, TopLevelFieldsAreStable) {
    const nlohmann::ordered_json j = nlohmann::ordered_json::parse(render_json(small_report()));
    std::vector<std::string> keys;
    for (auto it = j.begin(); it != j.end(); ++it) keys.push_back(it.key());
    EXPECT_EQ(keys,
              (std::vector<std::string>{"schema_version", "tool", "trace", "totals", "sizes",
                                        "commands", "overlap", "hazards", "timing", "notes"}));
}

TEST(RenderHtml, SelfContainedWithoutScriptOrNetwork) {
    for (const AnalysisReport& r : {small_report(), stream_report(300)}) {
        const std::string html = render_html(r);
        EXPECT_EQ(html.find("http://"), std::string::npos);
        EXPECT_EQ(html.find("https://"), std::string::npos);
        EXPECT_EQ(html.find("<script"), std::string::npos);
        EXPECT_EQ(html.find("<link"), std::string::npos);
        EXPECT_EQ(html.find("src="), std::string::npos);
        EXPECT_EQ(html.find("url("), std::string::npos);
        EXPECT_EQ(html.find("@import"), std::string::npos);
    }
}

TEST(RenderHtml, HasChartsTablesAndLinksWithTheRightNumbers) {
    const std::string html = render_html(small_report());
    for (const char* id :
         {"id=\"memory-map\"", "id=\"hist-build_triangle_cluster\"",
          "id=\"hist-build_clusters_bottom_level\"", "id=\"timeline\"", "id=\"sizes-table\"",
          "id=\"build-sizes-table\"", "id=\"hazard-table\"", "id=\"command-table\"",
          "id=\"overlap-pairs\"", "id=\"truncation-table\"", "id=\"cmd-0\"", "id=\"cmd-1\"",
          "id=\"cmd-2\"", "id=\"hazard-0\""})
        EXPECT_NE(html.find(id), std::string::npos) << id;
    EXPECT_EQ(count(html, "<rect class=\"region "), 14u);
    EXPECT_EQ(count(html, "<rect class=\"overlap hazard\""), 1u);
    EXPECT_EQ(count(html, "<rect class=\"overlap aliasing\""), 1u);
    EXPECT_EQ(count(html, "<rect class=\"overlap reuse\""), 3u);
    EXPECT_EQ(count(html, "<rect class=\"bar\" data-low"), 3u);  // blas: 1 bin, clas: 2 bins
    // Size budgets: blas objects 800 of 1000, scratch 512 of 4096; clas objects 5500 of 7400,
    // implicit 5500 of 7000, scratch 3072 of 8192.
    EXPECT_NE(html.find("id=\"size-budget\""), std::string::npos);
    EXPECT_EQ(count(html, "<rect class=\"budget-part "), 5u);
    EXPECT_NE(html.find("class=\"budget-part objects\" data-part=\"5500\" data-whole=\"7400\""),
              std::string::npos);
    EXPECT_NE(html.find("class=\"budget-part implicit\" data-part=\"5500\" data-whole=\"7000\""),
              std::string::npos);
    EXPECT_NE(html.find("class=\"budget-part scratch\" data-part=\"512\" data-whole=\"4096\""),
              std::string::npos);
    // Truncation: 2200/30, 2300/45, 1000/25 bytes per triangle.
    EXPECT_NE(html.find("data-bits=\"0\" data-bytes-per-triangle=\"73.33\""), std::string::npos);
    EXPECT_NE(html.find("data-bits=\"4\" data-bytes-per-triangle=\"51.11\""), std::string::npos);
    EXPECT_NE(html.find("data-bits=\"8\" data-bytes-per-triangle=\"40.00\""), std::string::npos);
    EXPECT_NE(html.find("data-low=\"512\" data-high=\"1023\" data-count=\"3\""), std::string::npos);
    EXPECT_EQ(count(html, "<rect class=\"replay\""), 3u);
    EXPECT_EQ(count(html, "<rect class=\"gpu\""), 3u);
    // The hazard row links both commands; the overlap row links the hazard.
    const std::size_t row = html.find("<tr id=\"hazard-0\"");
    ASSERT_NE(row, std::string::npos);
    const std::string hazard_row = html.substr(row, html.find('\n', row) - row);
    const std::size_t first = hazard_row.find("href=\"#cmd-1\"");
    ASSERT_NE(first, std::string::npos) << hazard_row;
    EXPECT_NE(hazard_row.find("href=\"#cmd-2\"", first), std::string::npos) << hazard_row;
    EXPECT_NE(html.find("<a href=\"#hazard-0\">hazard WRITE_AFTER_READ</a>"), std::string::npos);
    EXPECT_NE(html.find(
                  "<td>build_triangle_cluster</td><td class=\"num\">2</td><td class=\"num\">5</td>"
                  "<td class=\"num\">5</td><td class=\"num\">100</td><td class=\"num\">5500</td>"),
              std::string::npos);
}

TEST(RenderHtml, EscapesTraceText) {
    Analyzer a("<b>trace</b>");
    CommandInfo c;
    c.name = "<script>alert(1)</script>";
    a.on_command(c);
    a.on_region(RegionInfo{1, "\"><img onerror=x>", 0, 64, RegionRole::kScratch, true});
    const std::string html = render_html(a.finish());
    EXPECT_EQ(html.find("<script>"), std::string::npos);
    EXPECT_EQ(html.find("<img"), std::string::npos);
    EXPECT_EQ(html.find("<b>trace"), std::string::npos);
    EXPECT_NE(html.find("&lt;script&gt;alert(1)&lt;/script&gt;"), std::string::npos);
}

TEST(RenderHtml, LargeMapsDrawAtMostTheRegionCap) {
    const std::string html = render_html(stream_report(1000));  // 1000 * (2 + 8) regions
    EXPECT_EQ(count(html, "<rect class=\"region "), kMaxMapRegions);
    EXPECT_NE(html.find("smaller regions not drawn"), std::string::npos);
}

}  // namespace
}  // namespace clastrace::analyze

namespace clastrace::analyze {
namespace {

TEST(ReportOutput, WritesTheChosenFormatToAFile) {
    Analyzer a("out");
    synthetic::feed_small_scenario(a);
    const AnalysisReport r = a.finish();
    const std::string dir = ::testing::TempDir();
    std::string error;
    ASSERT_TRUE(write_report(r, ReportFormat::kHtml, dir + "/report.html", &error)) << error;
    std::ifstream in(dir + "/report.html");
    std::stringstream s;
    s << in.rdbuf();
    EXPECT_EQ(s.str(), render_html(r));
    EXPECT_FALSE(std::ifstream(dir + "/report.html.partial").good());
}

TEST(ReportOutput, UnwritablePathIsAClearError) {
    Analyzer a("out");
    const AnalysisReport r = a.finish();
    std::string error;
    EXPECT_FALSE(write_report(r, ReportFormat::kJson, "/nonexistent-dir/x/report.json", &error));
    EXPECT_NE(error.find("cannot write '/nonexistent-dir/x/report.json': cannot create"),
              std::string::npos)
        << error;
    EXPECT_NE(error.find("No such file or directory"), std::string::npos) << error;
}

}  // namespace
}  // namespace clastrace::analyze

namespace clastrace::analyze {
namespace {

// docs/analyze.md is the JSON reference: every field name the JSON uses must appear there.
void collect_keys(const nlohmann::json& j, std::set<std::string>& keys) {
    if (j.is_object()) {
        for (auto it = j.begin(); it != j.end(); ++it) {
            keys.insert(it.key());
            collect_keys(it.value(), keys);
        }
    } else if (j.is_array()) {
        for (const auto& v : j) collect_keys(v, keys);
    }
}

TEST(RenderJson, EveryFieldIsDocumented) {
    std::ifstream in(CLASTRACE_ANALYZE_DOC);
    ASSERT_TRUE(in) << CLASTRACE_ANALYZE_DOC;
    std::stringstream doc;
    doc << in.rdbuf();
    std::set<std::string> keys;
    collect_keys(nlohmann::json::parse(render_json(small_report())), keys);
    EXPECT_GT(keys.size(), 100u);
    // A name counts as documented inside code quotes: `name`, `a.name`, `name[]`, `name.b`, `name`:
    for (const std::string& k : keys) {
        bool documented = false;
        for (const char* before : {"`", "."})
            for (const char* after : {"`", "[", ".", ":"})
                documented |= doc.str().find(before + k + after) != std::string::npos;
        EXPECT_TRUE(documented) << k;
    }
}

}  // namespace
}  // namespace clastrace::analyze
