// SPDX-License-Identifier: Apache-2.0
// What a capture does to its output path (traces/output_file.h's rule): `clastrace capture`
// checks the program, the output and its options before the application starts, never empties
// an earlier file it does not replace, and two captures of one path never mix their bytes: the
// second is refused with one line, by the launcher before its application runs, or by the
// layer (enabled through the environment alone) while its application carries on.
#include "layer_launch_test.h"

#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>

#include <fcntl.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <thread>

extern char** environ;

namespace {

namespace fs = std::filesystem;
using clastrace::fbs::RecordBody;
using namespace clastrace::layer_launch;

constexpr const char* kAnotherCapture = "another process (another capture?) is writing it";

struct TraceSummary {
    bool opened = false, indexed = false;
    size_t submissions = 0;
    std::string error;
};

TraceSummary summarize(const fs::path& path) {
    TraceSummary s;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(path.string(), &error);
    if (!reader) {
        s.error = error.message;
        return s;
    }
    s.opened = true;
    s.indexed = reader->has_index();
    clastrace::traces::RecordView view;
    while (reader->next(&view))
        if (view.kind == RecordBody::QueueSubmit) ++s.submissions;
    return s;
}

size_t lines(const std::string& text) { return size_t(std::count(text.begin(), text.end(), '\n')); }

class CaptureOutput : public LayerLaunchTest {
protected:
    CaptureOutput() : LayerLaunchTest("clastrace_output") {}

    std::string cli(const std::string& args) const {
        return std::string(CLASTRACE_CLI) + " capture --layer-path " +
               CLASTRACE_LAYER_MANIFEST_DIR + " " + args;
    }
    std::string framesApp(const std::string& args) const {
        return std::string(CLASTRACE_FRAMES_APP) + " " + args;
    }

    // Starts `command` in the background, its output in dir/NAME.out and dir/NAME.err.
    pid_t startBackground(const std::string& command, std::map<std::string, std::string> env,
                          const std::string& layers, const std::string& name) {
        const std::string line = cleanEnvironment(std::move(env), layers) + " timeout 120 " +
                                 command + " >" + quote((dir / (name + ".out")).string()) + " 2>" +
                                 quote((dir / (name + ".err")).string());
        const char* argv[] = {"sh", "-c", line.c_str(), nullptr};
        pid_t pid = -1;
        return posix_spawn(&pid, "/bin/sh", nullptr, nullptr, const_cast<char**>(argv), environ) ==
                       0
                   ? pid
                   : -1;
    }
    ProcessResult finishBackground(pid_t pid, const std::string& name) {
        ProcessResult r;
        int status = 0;
        if (pid > 0 && waitpid(pid, &status, 0) == pid && WIFEXITED(status))
            r.exitCode = WEXITSTATUS(status);
        r.out = readText(dir / (name + ".out"));
        r.err = readText(dir / (name + ".err"));
        return r;
    }
    // Until the growing trace shows `submissions` QueueSubmit records: the first capture is
    // then past its device's creation (it holds the output) and waits for dir/go.
    bool waitForSubmissions(const fs::path& trace, size_t submissions) {
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(2);
        while (std::chrono::steady_clock::now() < deadline) {
            if (fs::exists(trace) && summarize(trace).submissions >= submissions) return true;
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
        return false;
    }
};

TEST_F(CaptureOutput, MissingProgramKeepsTheExistingFileAndSaysSoInOneLine) {
    const fs::path existing = dir / "earlier.clt";
    std::ofstream(existing) << "an earlier trace";
    for (const std::string program : {"clastrace-no-such-program", "/nonexistent/program"}) {
        ProcessResult r = run(cli("-o " + existing.string() + " -- " + program), {}, false);
        EXPECT_EQ(r.exitCode, 2) << program << ": " << r.err;
        EXPECT_EQ(lines(r.err), 1u) << r.err;
        EXPECT_NE(r.err.find("clastrace capture: cannot run '" + program + "'"), std::string::npos)
            << r.err;
        EXPECT_EQ(readText(existing), "an earlier trace");
    }
    // Found but not startable (its interpreter is missing): the failed exec is reported by the
    // child, and a file the launcher created for the capture is removed again.
    const fs::path script = dir / "broken.sh";
    std::ofstream(script) << "#!/nonexistent/interpreter\n";
    fs::permissions(script, fs::perms::owner_all);
    ProcessResult r =
        run(cli("-o " + (dir / "new.clt").string() + " -- " + script.string()), {}, false);
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_EQ(lines(r.err), 1u) << r.err;
    EXPECT_NE(r.err.find("cannot run '" + script.string() + "': No such file or directory"),
              std::string::npos)
        << r.err;
    EXPECT_FALSE(fs::exists(dir / "new.clt"));
}

TEST_F(CaptureOutput, EmptyOutputNameIsAUsageError) {
    ProcessResult r = run(cli("-o '' -- true"), {}, false);
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_EQ(lines(r.err), 1u) << r.err;
    EXPECT_NE(r.err.find("clastrace capture: -o names no file"), std::string::npos) << r.err;
}

TEST_F(CaptureOutput, MalformedSubmitRangeStopsBeforeTheApplicationRuns) {
    for (const std::string range : {"bogus", "5-2", "-3", "1-x"}) {
        ProcessResult r =
            run(cli("-o " + (dir / "x.clt").string() + " --submit-range " + range + " -- echo ran"),
                {}, false);
        EXPECT_EQ(r.exitCode, 2) << range << ": " << r.err;
        EXPECT_EQ(r.out.find("ran"), std::string::npos) << range;
        EXPECT_NE(r.err.find("is not a submission range"), std::string::npos) << r.err;
    }
    EXPECT_FALSE(fs::exists(dir / "x.clt"));
    ProcessResult r =
        run(cli("-o " + (dir / "x.clt").string() + " --submit-range 2- -- echo ran"), {}, false);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("ran"), std::string::npos);
}

// /dev/full (as a device of the test's own where it can make one): the layer says its write
// failed, and the launcher's line does not contradict it ("was not written" / "wrote").
TEST_F(CaptureOutput, FullDeviceGetsOneFailureAndNoContradiction) {
    fs::path device = dir / "full";
    const int probe = ::mknod(device.c_str(), S_IFCHR | 0666, makedev(1, 7)) == 0
                          ? ::open(device.c_str(), O_WRONLY)
                          : -1;
    if (probe < 0)
        device = "/dev/full";  // not root, or a file system mounted nodev
    else
        ::close(probe);
    ProcessResult r =
        run(cli("-o " + device.string() + " -- " + framesApp("frames 2 --clusters 8")), {}, false);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(count(r.err, "No space left on device"), 1u) << r.err;
    EXPECT_EQ(count(r.err, "clastrace capture:"), 1u) << r.err;
    EXPECT_EQ(r.err.find("was not written"), std::string::npos) << r.err;
    EXPECT_EQ(r.err.find("clastrace capture: wrote"), std::string::npos) << r.err;
    struct stat st {};
    ASSERT_EQ(::stat(device.c_str(), &st), 0);
    EXPECT_TRUE(S_ISCHR(st.st_mode));
}

// Through `clastrace capture`: the second launcher finds the output locked and stops before
// its application runs; the first finishes a complete trace. A later capture that replaces it,
// and one that writes nothing, say so.
TEST_F(CaptureOutput, SecondLauncherOfTheSamePathIsRefusedBeforeItsApplicationRuns) {
    const fs::path trace = dir / "shared.clt";
    const pid_t first =
        startBackground(cli("-o " + trace.string() + " -- " +
                            framesApp("frames 100 --clusters 8 --exit-at 3 --wait-for " +
                                      quote((dir / "go").string()))),
                        {}, "", "first");
    ASSERT_GT(first, 0);
    const bool started = waitForSubmissions(trace, 3);
    ProcessResult second =
        run(cli("-o " + trace.string() + " -- " + framesApp("frames 2 --clusters 8")), {}, false);
    std::ofstream(dir / "go") << "";
    ProcessResult r = finishBackground(first, "first");
    ASSERT_TRUE(started) << r.err;

    EXPECT_EQ(second.exitCode, 2) << second.err;
    EXPECT_EQ(lines(second.err), 1u) << second.err;
    EXPECT_NE(second.err.find(kAnotherCapture), std::string::npos) << second.err;
    EXPECT_EQ(second.out.find("frames="), std::string::npos)
        << "the second application ran: " << second.out;

    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("clastrace capture: wrote '" + trace.string() + "'"), std::string::npos)
        << r.err;
    TraceSummary t = summarize(trace);
    ASSERT_TRUE(t.opened) << t.error;
    EXPECT_TRUE(t.indexed);
    EXPECT_EQ(t.submissions, 4u);

    r = run(cli("-o " + trace.string() + " -- " + framesApp("frames 2 --clusters 8")), {}, false);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("clastrace capture: wrote '" + trace.string() + "' ("), std::string::npos)
        << r.err;
    EXPECT_NE(r.err.find(", replacing the earlier trace there"), std::string::npos) << r.err;
    EXPECT_EQ(summarize(trace).submissions, 2u);

    const std::string before = readText(trace);
    r = run(cli("-o " + trace.string() + " -- true"), {}, false);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(lines(r.err), 1u) << r.err;
    EXPECT_NE(r.err.find("was not written; the earlier trace there is kept"), std::string::npos)
        << r.err;
    EXPECT_EQ(readText(trace), before);
}

// The layer enabled through the environment alone: the second application's layer finds the
// output locked, says so in one line and the application runs on without capture; the first
// application's trace is complete and unmixed.
TEST_F(CaptureOutput, SecondLayerCaptureOfTheSamePathIsRefusedAndItsApplicationRuns) {
    const fs::path trace = dir / "shared.clt";
    const std::map<std::string, std::string> env{{"CLASTRACE_OUTPUT", trace.string()},
                                                 {"CLASTRACE_FLUSH_MS", "20"}};
    const pid_t first =
        startBackground(framesApp("frames 100 --clusters 8 --exit-at 3 --wait-for " +
                                  quote((dir / "go").string())),
                        env, kCaptureLayer, "first");
    ASSERT_GT(first, 0);
    const bool started = waitForSubmissions(trace, 3);
    ProcessResult second = run(framesApp("frames 2 --clusters 8"), env, true);
    std::ofstream(dir / "go") << "";
    ProcessResult r = finishBackground(first, "first");
    ASSERT_TRUE(started) << r.err;

    EXPECT_EQ(second.exitCode, 0) << second.err;
    EXPECT_NE(second.out.find("frames=2"), std::string::npos) << second.out;
    EXPECT_EQ(count(second.err, "clastrace:"), 1u) << second.err;
    EXPECT_NE(second.err.find("clastrace: capture disabled: cannot write '" + trace.string() +
                              "': " + kAnotherCapture),
              std::string::npos)
        << second.err;

    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.err.find("clastrace:"), std::string::npos) << r.err;
    TraceSummary t = summarize(trace);
    ASSERT_TRUE(t.opened) << t.error;
    EXPECT_TRUE(t.indexed);
    EXPECT_EQ(t.submissions, 4u);
}

}  // namespace
