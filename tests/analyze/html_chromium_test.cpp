// SPDX-License-Identifier: Apache-2.0
// Loads the HTML report in headless Chromium (Debian's `chromium`, installed by
// scripts/deps.sh): the rendered DOM must hold the charts and the right numbers, and a
// screenshot must come out. A missing chromium fails the test: CI installs it.
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "clastrace/analyze/render.h"
#include "synthetic_input.h"

namespace clastrace::analyze {
namespace {

namespace fs = std::filesystem;

struct CommandResult {
    int status = -1;
    std::string output;
};

CommandResult run(const std::string& command) {
    CommandResult r;
    FILE* pipe = popen((command + " 2>/dev/null").c_str(), "r");
    if (!pipe) return r;
    std::array<char, 65536> buf;
    std::size_t n;
    while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
    r.status = pclose(pipe);
    return r;
}

std::string chromium_command(const fs::path& profile) {
    // Flags keep the browser off the network and away from any existing profile; `timeout`
    // keeps a stuck browser from hanging the suite.
    return "timeout 60 chromium --headless --no-sandbox --disable-gpu --disable-quic "
           "--no-first-run "
           "--disable-background-networking --disable-component-update --disable-sync "
           "--disable-extensions "
           "--user-data-dir=" +
           profile.string();
}

std::size_t count(const std::string& s, const std::string& what) {
    std::size_t n = 0;
    for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + what.size())) ++n;
    return n;
}

class HtmlInChromium : public ::testing::Test {
protected:
    void SetUp() override {
        ASSERT_EQ(run("command -v chromium").status, 0)
            << "chromium is not installed: scripts/deps.sh installs it (apt-get install chromium)";
        dir_ = fs::path(CLASTRACE_ANALYZE_ARTIFACT_DIR);
        fs::create_directories(dir_);
        Analyzer a("small.clastrace");
        synthetic::feed_small_scenario(a);
        // One page per test: ctest runs the tests of this fixture in parallel processes.
        page_ = dir_ / (std::string("small_report_") +
                        ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".html");
        std::ofstream(page_) << render_html(a.finish());
        char tmpl[] = "/tmp/clastrace-chromium-XXXXXX";
        ASSERT_NE(mkdtemp(tmpl), nullptr);
        profile_ = tmpl;
    }
    void TearDown() override {
        std::error_code ec;
        if (!profile_.empty()) fs::remove_all(profile_, ec);
    }
    fs::path dir_, page_, profile_;
};

TEST_F(HtmlInChromium, DomHoldsChartsAndNumbers) {
    CommandResult r = run(chromium_command(profile_) + " --dump-dom file://" + page_.string());
    ASSERT_EQ(r.status, 0) << "chromium --dump-dom failed";
    const std::string& dom = r.output;
    ASSERT_NE(dom.find("<svg id=\"memory-map\""), std::string::npos) << dom.substr(0, 2000);
    EXPECT_NE(dom.find("<svg id=\"timeline\""), std::string::npos);
    EXPECT_NE(dom.find("<svg id=\"hist-build_triangle_cluster\""), std::string::npos);
    EXPECT_NE(dom.find("<svg id=\"hist-build_clusters_bottom_level\""), std::string::npos);
    EXPECT_EQ(count(dom, "<rect class=\"region "), 14u);
    EXPECT_EQ(count(dom, "<rect class=\"overlap hazard\""), 1u);
    EXPECT_NE(dom.find("<svg id=\"size-budget\""), std::string::npos);
    EXPECT_NE(dom.find("<svg id=\"truncation-chart\""), std::string::npos);
    EXPECT_NE(dom.find("data-low=\"512\" data-high=\"1023\" data-count=\"3\""), std::string::npos);
    // Tables as the browser parsed them (it inserts <tbody>).
    const std::size_t totals = dom.find("<table id=\"totals\">");
    ASSERT_NE(totals, std::string::npos);
    EXPECT_NE(dom.find("<td class=\"num\">3</td><td class=\"num\">2</td><td class=\"num\">6</td>"
                       "<td class=\"num\">6</td><td class=\"num\">160</td><td class=\"num\">14</td>"
                       "<td class=\"num\">5</td><td class=\"num\">1</td>",
                       totals),
              std::string::npos);
    EXPECT_NE(dom.find(
                  "<tr data-op-type=\"build_triangle_cluster\"><td>build_triangle_cluster</td>"
                  "<td class=\"num\">2</td><td class=\"num\">5</td><td class=\"num\">5</td>"
                  "<td class=\"num\">100</td><td class=\"num\">5500</td><td class=\"num\">900</td>"
                  "<td class=\"num\">1000</td><td class=\"num\">1400</td><td "
                  "class=\"num\">55.00</td></tr>"),
              std::string::npos);
    EXPECT_NE(dom.find("<tr id=\"hazard-0\" class=\"hazard-row\"><td "
                       "class=\"num\">0</td><td>WRITE_AFTER_READ</td>"
                       "<td class=\"num\"><a href=\"#cmd-1\">1</a></td>"
                       "<td class=\"num\"><a href=\"#cmd-2\">2</a></td>"),
              std::string::npos);
    EXPECT_NE(dom.find("<tr id=\"cmd-2\" class=\"hazard-row\">"), std::string::npos);
}

TEST_F(HtmlInChromium, ScreenshotComesOut) {
    const fs::path png = dir_ / "small_report.png";
    fs::remove(png);
    CommandResult r =
        run(chromium_command(profile_) +
            " --hide-scrollbars --window-size=1280,2000 --screenshot=" + png.string() + " file://" +
            page_.string());
    ASSERT_EQ(r.status, 0) << "chromium --screenshot failed";
    ASSERT_TRUE(fs::exists(png));
    EXPECT_GT(fs::file_size(png), 40u * 1024u) << "screenshot suspiciously small: an empty page?";
    std::ifstream in(png, std::ios::binary);
    std::array<char, 8> sig{};
    in.read(sig.data(), 8);
    EXPECT_EQ(std::string(sig.data() + 1, 3), "PNG");
    std::cout << "screenshot: " << png << "\n";
}

}  // namespace
}  // namespace clastrace::analyze
