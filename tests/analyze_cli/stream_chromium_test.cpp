// SPDX-License-Identifier: Apache-2.0
// The HTML report of a generated trace (analyze_scene.h: a safe scratch reuse, GPU timestamp
// spans, all command kinds) loaded in headless Chromium: the DOM must hold the GPU timeline,
// the command-kind table, the memory map's regions and the numbers the trace implies.
#include "analyze_scene.h"

#include <clastrace/analyze/render.h>
#include <clastrace/analyze/replay_stream.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <unistd.h>

namespace clastrace {
namespace {

namespace fs = std::filesystem;

std::string run(const std::string& command, int* status) {
    std::string out;
    FILE* pipe = popen((command + " 2>/dev/null").c_str(), "r");
    if (!pipe) return out;
    std::array<char, 65536> buf;
    std::size_t n;
    while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) out.append(buf.data(), n);
    *status = pclose(pipe);
    return out;
}

std::size_t count(const std::string& s, const std::string& what) {
    std::size_t n = 0;
    for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + what.size())) ++n;
    return n;
}

TEST(StreamHtmlInChromium, GpuTimelineKindsAndMap) {
    int status = -1;
    run("command -v chromium", &status);
    ASSERT_EQ(status, 0)
        << "chromium is not installed: scripts/deps.sh installs it (apt-get install chromium)";
    const fs::path dir(CLASTRACE_ANALYZE_ARTIFACT_DIR);
    fs::create_directories(dir);
    const std::string trace = (dir / "stream_scene.clt").string();
    uint64_t engine_bytes = 0;
    {
        test::AnalyzeSceneWriter w(trace, 2.0f);
        w.timestamp(1000);
        test::ClusterBuild a;
        a.triangle_counts = {2, 8, 18};
        for (uint64_t s : w.build(a).engine_sizes) engine_bytes += s;
        w.timestamp(1600);
        w.build_to_build_barrier();
        test::ClusterBuild b;
        b.triangle_counts = {4, 4};
        b.dst = test::AnalyzeScene::kPool + 0x20000;
        b.scratch = test::AnalyzeScene::kPool + 0x30000;
        b.arrays = test::AnalyzeScene::kArrays + 0x400;
        for (uint64_t s : w.build(b).engine_sizes) engine_bytes += s;
        w.timestamp(2600);
        w.nv_build(24, 12345, 2048);
        w.deserialize(256, 4096);
        w.timestamp(3100);
        w.calibrate(1000, 5'000'000, 250);
        w.submit();
        w.finish();
    }
    traces::TraceError e;
    auto reader = traces::TraceReader::open(trace, &e);
    ASSERT_TRUE(reader) << e.message;
    const analyze::TraceAnalysis a = analyze::analyze_trace(*reader, "stream_scene.clt");
    const fs::path page = dir / "stream_scene_report.html";
    std::ofstream(page) << analyze::render_html(a.report);

    char tmpl[] = "/tmp/clastrace-chromium-XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    const std::string chromium =
        "timeout 60 chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
        "--disable-background-networking --disable-component-update --disable-sync "
        "--disable-extensions "
        "--user-data-dir=" +
        std::string(tmpl);
    const std::string dom = run(chromium + " --dump-dom file://" + page.string(), &status);
    ASSERT_EQ(status, 0) << "chromium --dump-dom failed";

    ASSERT_NE(dom.find("<svg id=\"gpu-timeline\""), std::string::npos) << dom.substr(0, 2000);
    EXPECT_EQ(count(dom, "<rect class=\"gpu-span gpu\""), 3u);
    EXPECT_NE(dom.find("data-first=\"1\" data-last=\"1\" data-start-ns=\"0\" data-ns=\"1200\""),
              std::string::npos);
    EXPECT_NE(dom.find("data-first=\"3\" data-last=\"4\" data-start-ns=\"1200\" data-ns=\"2000\""),
              std::string::npos);
    EXPECT_NE(dom.find("data-first=\"6\" data-last=\"7\" data-start-ns=\"3200\" data-ns=\"1000\" "
                       "data-ops=\"2\""),
              std::string::npos);
    // GPU spans table: the last span on the host clock (tick 1000 = 5 ms, 2 ns per tick).
    EXPECT_NE(
        dom.find(
            "<td class=\"num\">3200</td><td class=\"num\">5003200</td><td class=\"num\">1000</td>"),
        std::string::npos);
    // Command kinds, all of them.
    EXPECT_NE(
        dom.find("<tr data-name=\"vkCmdBuildClusterAccelerationStructureIndirectNV\">"
                 "<td>vkCmdBuildClusterAccelerationStructureIndirectNV</td><td class=\"num\">2</td>"
                 "<td class=\"num\">5</td><td class=\"num\">36</td><td class=\"num\">5</td><td "
                 "class=\"num\">" +
                 std::to_string(engine_bytes) + "</td><td class=\"num\">" +
                 std::to_string(engine_bytes + 5 * 128) + "</td>"),
        std::string::npos);
    {
        // The NV build: 1 command, 1 op, 8 triangles, the one bottom level the replay rebuilt
        // (engine bytes are the engine's), and the driver's 12345-byte requirement.
        const size_t row = dom.find(
            "<tr "
            "data-name=\"vkCmdBuildAccelerationStructureNV\"><td>vkCmdBuildAccelerationStructureNV<"
            "/td>");
        ASSERT_NE(row, std::string::npos);
        const std::string cells = dom.substr(row, dom.find("</tr>", row) - row);
        EXPECT_NE(cells.find("<td class=\"num\">1</td><td class=\"num\">1</td><td "
                             "class=\"num\">8</td><td class=\"num\">1</td>"),
                  std::string::npos)
            << cells;
        EXPECT_NE(cells.find("</td><td class=\"num\">12345</td>"), std::string::npos) << cells;
        EXPECT_EQ(cells.find("<td class=\"num\">0</td><td class=\"num\">12345</td>"),
                  std::string::npos)
            << cells;
    }
    EXPECT_NE(dom.find("<tr data-name=\"vkCmdCopyMemoryToAccelerationStructureKHR\">"),
              std::string::npos);
    EXPECT_NE(dom.find("<tr data-name=\"vkCmdPipelineBarrier2\">"), std::string::npos);
    // The memory map draws the scratch, implicit data and objects; the reuse is outlined, not a hazard.
    EXPECT_NE(dom.find("<svg id=\"memory-map\""), std::string::npos);
    EXPECT_GT(count(dom, "role-scratch"), 0u);
    EXPECT_GT(count(dom, "role-implicit_data"), 0u);
    EXPECT_GT(count(dom, "role-object_clas"), 0u);
    EXPECT_EQ(count(dom, "<rect class=\"overlap hazard\""), 0u);
    EXPECT_EQ(count(dom, "<rect class=\"overlap reuse\""), 1u);
    EXPECT_NE(dom.find("<p id=\"largest-submission\" data-submission=\"0\" data-commands=\"5\" "
                       "data-ops=\"7\">"),
              std::string::npos);

    const fs::path png = dir / "stream_scene_report.png";
    fs::remove(png);
    run(chromium + " --hide-scrollbars --window-size=1280,2400 --screenshot=" + png.string() +
            " file://" + page.string(),
        &status);
    EXPECT_EQ(status, 0);
    EXPECT_TRUE(fs::exists(png));
    std::error_code ec;
    fs::remove_all(tmpl, ec);
    fs::remove(trace);
}

}  // namespace
}  // namespace clastrace
