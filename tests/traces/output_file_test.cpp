// SPDX-License-Identifier: Apache-2.0
// The output-file rule (clastrace/traces/output_file.h): what writing an output does to each
// kind of thing already at the path.
#include "trace_test_support.h"

#include <clastrace/traces/output_file.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>

namespace clastrace::traces::testing {
namespace {

namespace fs = std::filesystem;

std::string read_text(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
}

void write_text(const std::string& path, const std::string& text) {
    std::ofstream(path, std::ios::binary) << text;
}

// A fresh directory for one test.
std::string fresh_dir(const std::string& name) {
    const std::string dir = temp_path(name);
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

size_t entries_in(const std::string& dir) {
    return size_t(std::distance(fs::directory_iterator(dir), fs::directory_iterator()));
}

TEST(OutputFile, NothingAtThePathGetsANewFileAndNoTemporaryIsLeft) {
    const std::string dir = fresh_dir("output_new");
    std::string error;
    ASSERT_TRUE(write_output_file(dir + "/report.html", "new", &error)) << error;
    EXPECT_EQ(read_text(dir + "/report.html"), "new");
    EXPECT_EQ(entries_in(dir), 1u);
}

TEST(OutputFile, RegularFileIsReplacedWholeWithItsPermissions) {
    const std::string dir = fresh_dir("output_regular");
    const std::string path = dir + "/report.html";
    write_text(path, "an earlier, longer report");
    ::chmod(path.c_str(), 0640);
    struct stat before {};
    ::stat(path.c_str(), &before);
    std::string error;
    ASSERT_TRUE(write_output_file(path, "new", &error)) << error;
    struct stat after {};
    ::stat(path.c_str(), &after);
    EXPECT_EQ(read_text(path), "new");
    EXPECT_NE(after.st_ino, before.st_ino);  // renamed over, not rewritten in place
    EXPECT_EQ(after.st_mode & 07777, 0640u);
    EXPECT_EQ(entries_in(dir), 1u);
}

TEST(OutputFile, SymbolicLinkStaysAndItsTargetIsReplaced) {
    const std::string dir = fresh_dir("output_link");
    fs::create_directories(dir + "/real");
    write_text(dir + "/real/target.html", "old");
    fs::create_symlink("real/target.html", dir + "/link.html");  // relative to the link's folder
    std::string error;
    ASSERT_TRUE(write_output_file(dir + "/link.html", "new", &error)) << error;
    EXPECT_TRUE(fs::is_symlink(dir + "/link.html"));
    EXPECT_EQ(fs::read_symlink(dir + "/link.html"), "real/target.html");
    EXPECT_EQ(read_text(dir + "/real/target.html"), "new");
    EXPECT_EQ(entries_in(dir + "/real"), 1u);
}

TEST(OutputFile, DanglingLinkCreatesItsTarget) {
    const std::string dir = fresh_dir("output_dangling");
    fs::create_symlink(dir + "/made.html", dir + "/link.html");
    std::string error;
    ASSERT_TRUE(write_output_file(dir + "/link.html", "new", &error)) << error;
    EXPECT_TRUE(fs::is_symlink(dir + "/link.html"));
    EXPECT_EQ(read_text(dir + "/made.html"), "new");
}

TEST(OutputFile, FifoIsWrittenInPlaceAndStaysAFifo) {
    const std::string dir = fresh_dir("output_fifo");
    const std::string path = dir + "/pipe";
    ASSERT_EQ(::mkfifo(path.c_str(), 0600), 0);
    std::string error;
    EXPECT_FALSE(write_output_file(path, "nobody reads", &error));  // refused, not waited for
    EXPECT_NE(error.find("no process is reading this FIFO"), std::string::npos) << error;
    const int reader = ::open(path.c_str(), O_RDONLY | O_NONBLOCK);
    ASSERT_GE(reader, 0);
    ASSERT_TRUE(write_output_file(path, "through the pipe", &error)) << error;
    char got[64] = {};
    const ssize_t n = ::read(reader, got, sizeof got);
    ::close(reader);
    EXPECT_EQ(std::string(got, n > 0 ? size_t(n) : 0), "through the pipe");
    EXPECT_TRUE(fs::is_fifo(path));
    EXPECT_EQ(entries_in(dir), 1u);
}

// A null device of the test's own where it may make one (as root, where a broken rule would
// replace the system's /dev/null), else /dev/null itself (which a non-root run cannot replace).
std::string own_device(const std::string& dir, const std::string& name, unsigned minor) {
    const std::string own = dir + "/" + name;
    if (::mknod(own.c_str(), S_IFCHR | 0666, makedev(1, minor)) != 0) return "/dev/" + name;
    const int fd = ::open(own.c_str(), O_WRONLY);  // a file system mounted nodev refuses it
    if (fd < 0) return "/dev/" + name;
    ::close(fd);
    return own;
}
std::string null_device(const std::string& dir) { return own_device(dir, "null", 3); }

TEST(OutputFile, NullDeviceStaysACharacterDevice) {
    const std::string dir = fresh_dir("output_devnull");
    const std::string device = null_device(dir);
    std::string error;
    ASSERT_TRUE(write_output_file(device, "discarded", &error)) << error;
    EXPECT_TRUE(fs::is_character_file(device));
    EXPECT_EQ(read_text(device), "");
    // A link to it: the device is written, the link stays.
    fs::create_symlink(device, dir + "/link");
    ASSERT_TRUE(write_output_file(dir + "/link", "discarded", &error)) << error;
    EXPECT_TRUE(fs::is_symlink(dir + "/link"));
    EXPECT_TRUE(fs::is_character_file(device));
}

TEST(OutputFile, DeviceThatRefusesBytesIsAFailureNamingIt) {
    const std::string device = own_device(fresh_dir("output_devfull"), "full", 7);
    std::string error;
    EXPECT_FALSE(write_output_file(device, "x", &error));
    EXPECT_NE(error.find("cannot write '" + device + "': write failed: No space left on device"),
              std::string::npos)
        << error;
    EXPECT_TRUE(fs::is_character_file(device));
}

TEST(OutputFile, DirectoryAndEmptyNameAreRefused) {
    const std::string dir = fresh_dir("output_dir");
    std::string error;
    EXPECT_FALSE(write_output_file(dir, "x", &error));
    EXPECT_NE(error.find("it is a directory"), std::string::npos) << error;
    EXPECT_FALSE(probe_output(dir, &error));
    EXPECT_FALSE(write_output_file("", "x", &error));
    EXPECT_NE(error.find("name is empty"), std::string::npos) << error;
    EXPECT_TRUE(fs::is_directory(dir));
}

TEST(OutputFile, ProbeCreatesAndEmptiesNothing) {
    const std::string dir = fresh_dir("output_probe");
    std::string error;
    EXPECT_TRUE(probe_output(dir + "/absent.json", &error)) << error;
    EXPECT_FALSE(fs::exists(dir + "/absent.json"));
    write_text(dir + "/kept.json", "kept");
    EXPECT_TRUE(probe_output(dir + "/kept.json", &error)) << error;
    EXPECT_EQ(read_text(dir + "/kept.json"), "kept");
    EXPECT_FALSE(probe_output(dir + "/missing-dir/x.json", &error));
    EXPECT_NE(error.find("cannot write '" + dir + "/missing-dir/x.json': "), std::string::npos)
        << error;
}

// A trace is written in place under a lock: the earlier file is untouched until the writer
// starts, and a second writer of the same file is refused instead of mixing its bytes in.
TEST(OutputFile, InPlaceOutputIsLockedAndEmptiedOnlyWhenWritingStarts) {
    const std::string dir = fresh_dir("output_in_place");
    const std::string path = dir + "/trace.clt";
    write_text(path, "an earlier trace");
    OutputTarget target;
    std::string error;
    const int fd = open_output_in_place(path, &target, &error);
    ASSERT_GE(fd, 0) << error;
    EXPECT_EQ(read_text(path), "an earlier trace");

    OutputTarget second;
    EXPECT_LT(open_output_in_place(path, &second, &error), 0);
    EXPECT_NE(error.find("another process (another capture?) is writing it"), std::string::npos)
        << error;
    TraceError trace_error;
    EXPECT_FALSE(TraceWriter::create(path, test_header(), {}, &trace_error));
    EXPECT_NE(trace_error.message.find("holds its lock"), std::string::npos) << trace_error.message;
    EXPECT_EQ(read_text(path), "an earlier trace");

    auto writer = TraceWriter::create_on(fd, path, test_header(), {}, &trace_error);
    ASSERT_TRUE(writer) << trace_error.message;
    ASSERT_FALSE(writer->finish());
    auto reader = TraceReader::open(path, &trace_error);
    ASSERT_TRUE(reader) << trace_error.message;
    EXPECT_TRUE(reader->has_index());
    // Finished and closed: the lock is gone with the descriptor.
    const int again = open_output_in_place(path, &second, &error);
    EXPECT_GE(again, 0) << error;
    ::close(again);
}

}  // namespace
}  // namespace clastrace::traces::testing
