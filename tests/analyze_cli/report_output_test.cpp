// SPDX-License-Identifier: Apache-2.0
// `clastrace analyze --html OUT` follows the output-file rule (clastrace/traces/output_file.h):
// a symbolic link keeps being a link to the new report, a device stays a device.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace clastrace {
namespace {

namespace fs = std::filesystem;

std::string read_text(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
}

fs::path fresh_dir(const std::string& name) {
    const fs::path dir = fs::temp_directory_path() /
                         ("clastrace_report_output_" + std::to_string(::getpid())) / name;
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

int analyze_html(const std::string& out, const fs::path& log) {
    const std::string cmd = std::string(CLASTRACE_BIN) + " analyze " + CLASTRACE_SAMPLE +
                            " --html '" + out + "' >'" + log.string() + "' 2>&1";
    const int status = std::system(cmd.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(AnalyzeReportOutput, HtmlThroughASymbolicLinkReplacesTheTargetAndKeepsTheLink) {
    const fs::path dir = fresh_dir("link");
    fs::create_directories(dir / "reports");
    std::ofstream(dir / "reports" / "latest.html") << "an earlier report";
    fs::create_symlink("reports/latest.html", dir / "report.html");
    ASSERT_EQ(analyze_html((dir / "report.html").string(), dir / "log.txt"), 0)
        << read_text(dir / "log.txt");
    EXPECT_TRUE(fs::is_symlink(dir / "report.html"));
    EXPECT_EQ(fs::read_symlink(dir / "report.html"), "reports/latest.html");
    EXPECT_EQ(read_text(dir / "reports" / "latest.html").rfind("<!DOCTYPE html>", 0), 0u);
    EXPECT_EQ(std::distance(fs::directory_iterator(dir / "reports"), fs::directory_iterator()), 1);
}

// A null device of the test's own where it may make one (as root, where a broken rule would
// replace the system's /dev/null), else /dev/null itself (which a non-root run cannot replace).
fs::path null_device(const fs::path& dir) {
    const fs::path own = dir / "null";
    if (::mknod(own.c_str(), S_IFCHR | 0666, makedev(1, 3)) != 0) return "/dev/null";
    const int fd = ::open(own.c_str(), O_WRONLY);  // a file system mounted nodev refuses it
    if (fd < 0) return "/dev/null";
    ::close(fd);
    return own;
}

TEST(AnalyzeReportOutput, HtmlToANullDeviceLeavesTheDevice) {
    const fs::path dir = fresh_dir("devnull");
    const fs::path device = null_device(dir);
    ASSERT_EQ(analyze_html(device.string(), dir / "log.txt"), 0) << read_text(dir / "log.txt");
    struct stat st {};
    ASSERT_EQ(::stat(device.c_str(), &st), 0);
    EXPECT_TRUE(S_ISCHR(st.st_mode));
    EXPECT_EQ(read_text(device), "");
}

TEST(AnalyzeReportOutput, HtmlOntoADirectoryIsRefusedWithExit2) {
    const fs::path dir = fresh_dir("directory");
    fs::create_directories(dir / "out.html");
    EXPECT_EQ(analyze_html((dir / "out.html").string(), dir / "log.txt"), 2);
    EXPECT_NE(read_text(dir / "log.txt").find("it is a directory"), std::string::npos)
        << read_text(dir / "log.txt");
    EXPECT_TRUE(fs::is_directory(dir / "out.html"));
}

}  // namespace
}  // namespace clastrace
