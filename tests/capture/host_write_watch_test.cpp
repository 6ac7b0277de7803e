// SPDX-License-Identifier: Apache-2.0
// The host-write watch (capture/README.md, "Host writes") through the loader on lavapipe, in both
// of its modes: every case that holds with the hash watch must hold with the page guard. The
// application is tests/apps/cluster_capture_app host-rewrite; replay counts the races the trace's
// MemoryObservation records make.
#include "layer_launch_test.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace {

using namespace clastrace::layer_launch;

class HostWriteWatchRun : public LayerLaunchTest {
protected:
    HostWriteWatchRun() : LayerLaunchTest("clastrace_host_writes") {}

    struct Outcome {
        int app_exit = -1;
        size_t races = 0;
        std::string watch_line;  // the stats line naming the watch's mode
        std::string log;
    };

    // Runs `host-rewrite ARGS` with the watch in `mode`, then replays its trace.
    Outcome rewrite(const std::string& args, const std::string& mode,
                    std::map<std::string, std::string> env = {}) {
        const std::string trace = (dir / "trace.clt").string();
        env["CLASTRACE_OUTPUT"] = trace;
        env["CLASTRACE_HOST_WRITES"] = mode;
        env["CLASTRACE_STATS"] = "1";
        ProcessResult r = run(std::string(CLASTRACE_CAPTURE_APP) + " host-rewrite " + args, env);
        Outcome o;
        o.app_exit = r.exitCode;
        o.log = r.err;
        const size_t at = r.err.find("host-write watch: ");
        if (at != std::string::npos) o.watch_line = r.err.substr(at, r.err.find('\n', at) - at);
        ProcessResult replayed =
            run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay " + trace, {}, false);
        for (size_t p = replayed.out.find("HOST-WRITE race"); p != std::string::npos;
             p = replayed.out.find("HOST-WRITE race", p + 1))
            ++o.races;
        o.log += replayed.out;
        return o;
    }
};

struct Case {
    const char* args;
    size_t races;  // what replay finds: the app is correct apart from its rewrite
};

// The rewrite's timing (before the fence wait, after it, before the build ran) with the infos in
// an allocation of their own (under a page: the guard leaves it to the hash) and on a page the
// guard protects; a write beside the infos on their page; a rewrite from another thread; an
// application with its own SIGSEGV handler; the served build writing on the infos' page.
const std::vector<Case> kCases = {
    {"before-wait", 1},
    {"after-wait", 0},
    {"before-run", 1},
    {"before-wait paged", 1},
    {"after-wait paged", 0},
    {"before-run paged", 1},
    {"before-wait neighbour", 0},
    {"before-wait thread", 1},
    {"before-wait app-handler", 1},
    {"before-wait layer-writes", 0},
};

TEST_F(HostWriteWatchRun, EveryCaseGivesTheSameRacesWithTheHashWatchAndThePageGuard) {
    for (const char* mode : {"hash", "guard"})
        for (const Case& c : kCases) {
            SCOPED_TRACE(std::string(mode) + ": " + c.args);
            const Outcome o = rewrite(c.args, mode);
            ASSERT_EQ(o.app_exit, 0) << o.log;  // app-handler: 4 unless its handler saw its fault
            EXPECT_EQ(o.races, c.races) << o.log;
            if (std::string(mode) == "hash") {
                EXPECT_EQ(o.watch_line.rfind("host-write watch: hash: ", 0), 0u) << o.log;
            } else {
                EXPECT_EQ(o.watch_line.rfind("host-write watch: guard: ", 0), 0u) << o.log;
                // The paged infos are protected, not hashed; the small allocations are hashed.
                const bool paged = std::string(c.args).find(' ') != std::string::npos;
                EXPECT_EQ(o.watch_line.find("guard: 0 ranges write-protected") == std::string::npos,
                          paged)
                    << o.watch_line;
            }
        }
}

// A write on the infos' page that is not to the infos, and the served build's own writes there:
// the guard sees the page written (a fault) and compares, and nothing is reported.
TEST_F(HostWriteWatchRun, WritesBesideTheWatchedBytesFaultButAreNotReported) {
    for (const char* place : {"neighbour", "layer-writes"}) {
        const Outcome o = rewrite(std::string("before-wait ") + place, "guard");
        ASSERT_EQ(o.app_exit, 0) << o.log;
        EXPECT_EQ(o.races, 0u) << o.log;
        EXPECT_EQ(o.watch_line.find(", 0 pages written while protected"), std::string::npos)
            << place << ": " << o.watch_line;
    }
}

// mprotect refuses to make the pages read-only (an LD_PRELOAD shim): every range is hashed, the
// stats say so, and the race is still found.
TEST_F(HostWriteWatchRun, RefusedMprotectFallsBackToHashing) {
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    GTEST_SKIP() << "an LD_PRELOAD shim cannot come before a sanitizer's runtime";
#endif
    const Outcome o =
        rewrite("before-wait paged", "guard", {{"LD_PRELOAD", CLASTRACE_MPROTECT_REFUSING_SHIM}});
    ASSERT_EQ(o.app_exit, 0) << o.log;
    EXPECT_EQ(o.races, 1u) << o.log;
    EXPECT_EQ(o.watch_line.rfind("host-write watch: guard: 0 ranges write-protected", 0), 0u)
        << o.watch_line;
    EXPECT_EQ(o.watch_line.find("(0 refused by mprotect)"), std::string::npos) << o.watch_line;
}

// A frame loop (tests/capture/capture_frames_app) whose host rewrites a vertex after submitting
// frame 6, before its wait: the submission's walks were reused from frame 1 on (the stats say
// so), and the race is found as with a fresh walk, in both modes; without the rewrite, none.
TEST_F(HostWriteWatchRun, ARaceOnAResubmittedCommandIsFoundThroughItsReusedWalk) {
    const std::string trace = (dir / "frames.clt").string();
    for (const char* mode : {"hash", "guard"})
        for (const char* race : {"", " --race-at 6"}) {
            SCOPED_TRACE(std::string(mode) + race);
            ProcessResult r = run(std::string(CLASTRACE_FRAMES_APP) +
                                      " frames 8 --clusters 64 --host-infos" + race,
                                  {{"CLASTRACE_OUTPUT", trace},
                                   {"CLASTRACE_HOST_WRITES", mode},
                                   {"CLASTRACE_TRACEABLE_CLUSTERS", "0"},
                                   {"CLASTRACE_STATS", "1"}});
            ASSERT_EQ(r.exitCode, 0) << r.err;
            if (std::string(mode) == "guard") {
                EXPECT_NE(r.err.find("14 of 16 walks reused"), std::string::npos) << r.err;
            }
            ProcessResult replayed =
                run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay " + trace, {}, false);
            size_t races = 0;
            for (size_t p = replayed.out.find("HOST-WRITE race"); p != std::string::npos;
                 p = replayed.out.find("HOST-WRITE race", p + 1))
                ++races;
            EXPECT_EQ(races, *race ? 1u : 0u) << replayed.out;
        }
}

// CLASTRACE_HOST_WRITES=0: no watch, no observation, and the stats say so.
TEST_F(HostWriteWatchRun, OffWatchesNothing) {
    const Outcome o = rewrite("before-wait paged", "0");
    ASSERT_EQ(o.app_exit, 0) << o.log;
    EXPECT_EQ(o.races, 0u) << o.log;
    EXPECT_EQ(o.watch_line, "host-write watch: off") << o.log;
}

}  // namespace
