// SPDX-License-Identifier: Apache-2.0
// The layer under stress, on lavapipe through the loader: write failures, applications that
// exit, abort or are killed mid-frame, simultaneous-use command buffers, memory the host cannot
// map (forced staging), host synchronization records and the engine's findings in the trace.
#include "layer_launch_test.h"

#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>

#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <thread>
#include <tuple>

extern char** environ;

namespace {

namespace fs = std::filesystem;
using clastrace::fbs::RecordBody;
using clastrace::traces::TraceReader;

using namespace clastrace::layer_launch;

// What a test needs to know of a trace: record kinds in order, each cluster build's snapshots
// with their bytes, and the damage the reader reported.
struct TraceContents {
    bool opened = false;
    std::string openError;
    bool indexed = false;
    std::vector<RecordBody> kinds;
    struct Snapshot {
        uint64_t address;
        std::string bytes;
    };
    std::vector<std::vector<Snapshot>> buildInputs, buildOutputs;
    std::vector<const char*> damage;  // trace_error_code_name of each problem
    size_t count(RecordBody kind) const {
        return size_t(std::count(kinds.begin(), kinds.end(), kind));
    }
};

TraceContents readTrace(const fs::path& path) {
    TraceContents t;
    clastrace::traces::TraceError error;
    auto reader = TraceReader::open(path.string(), &error);
    if (!reader) {
        t.openError = error.message;
        return t;
    }
    t.opened = true;
    t.indexed = reader->has_index();
    clastrace::traces::RecordView view;
    std::vector<std::pair<uint64_t, uint64_t>> inputs, outputs;
    std::vector<std::vector<std::pair<uint64_t, uint64_t>>> allInputs, allOutputs;
    while (reader->next(&view)) {
        t.kinds.push_back(view.kind);
        if (view.kind != RecordBody::CmdBuildClusterAccelerationStructureIndirect) continue;
        const auto* build = view.record->body_as_CmdBuildClusterAccelerationStructureIndirect();
        std::vector<std::pair<uint64_t, uint64_t>> in, out;
        if (build->inputs())
            for (const auto* s : *build->inputs()) in.emplace_back(s->address(), s->hash());
        if (build->outputs())
            for (const auto* s : *build->outputs()) out.emplace_back(s->address(), s->hash());
        allInputs.push_back(in);
        allOutputs.push_back(out);
    }
    auto resolve = [&](const std::vector<std::vector<std::pair<uint64_t, uint64_t>>>& lists,
                       std::vector<std::vector<TraceContents::Snapshot>>& into) {
        for (const auto& list : lists) {
            into.emplace_back();
            for (const auto& [address, hash] : list) {
                std::vector<uint8_t> bytes;
                auto e = reader->read_contents(hash, &bytes);
                into.back().push_back({address, e ? "<" + e.message + ">" : hexOf(bytes)});
            }
        }
    };
    resolve(allInputs, t.buildInputs);
    resolve(allOutputs, t.buildOutputs);
    for (const auto& e : reader->damage())
        t.damage.push_back(clastrace::traces::trace_error_code_name(e.code));
    return t;
}

class CaptureRobustness : public LayerLaunchTest {
    friend void expectSameBytesForEachValue(CaptureRobustness& test, const std::string& variable,
                                            const std::vector<std::string>& values);

protected:
    CaptureRobustness() : LayerLaunchTest("clastrace_robust") {}

    // The shell line that runs `args` of the frames app under `layers` with `env` on top of a
    // clean environment; `prefix` runs first in the same shell (ulimit, trap).
    std::string commandLine(const std::string& args, std::map<std::string, std::string> env,
                            const std::string& prefix = "",
                            const std::string& layers = kCaptureLayer) {
        return prefix + "exec " + cleanEnvironment(std::move(env), layers) + " " +
               CLASTRACE_FRAMES_APP + " " + args + " >" + quote((dir / "stdout.txt").string()) +
               " 2>" + quote((dir / "stderr.txt").string());
    }

    // The process runs in a process group of its own (its id is `pid`), so that killing the group
    // reaches the application under the shell and `timeout`.
    pid_t start(const std::string& line) {
        // --foreground: timeout stays in this group instead of making one of its own.
        const std::string shell = "timeout --foreground -s KILL 180 sh -c " + quote(line);
        const char* argv[] = {"sh", "-c", shell.c_str(), nullptr};
        posix_spawnattr_t attributes;
        posix_spawnattr_init(&attributes);
        posix_spawnattr_setflags(&attributes, POSIX_SPAWN_SETPGROUP);
        posix_spawnattr_setpgroup(&attributes, 0);
        pid_t pid = -1;
        const int failed =
            posix_spawn(&pid, "/bin/sh", nullptr, &attributes, const_cast<char**>(argv), environ);
        posix_spawnattr_destroy(&attributes);
        return failed ? -1 : pid;
    }

    ProcessResult finish(pid_t pid) {
        ProcessResult r;
        int status = 0;
        if (pid > 0 && waitpid(pid, &status, 0) == pid) {
            if (WIFEXITED(status)) r.exitCode = WEXITSTATUS(status);
            // timeout and sh report a killed child as 128 + signal
            if (r.exitCode > 128) r.exitCode = -(r.exitCode - 128);
            if (WIFSIGNALED(status)) r.exitCode = -WTERMSIG(status);
        }
        r.out = readText(dir / "stdout.txt");
        r.err = readText(dir / "stderr.txt");
        return r;
    }

    ProcessResult run(const std::string& args, std::map<std::string, std::string> env,
                      const std::string& prefix = "") {
        return finish(start(commandLine(args, std::move(env), prefix)));
    }

    // Reads the growing trace until it holds `submissions` QueueSubmit records (the periodic
    // flush must bring them out while the application still runs). False after two minutes.
    bool waitForSubmissions(const fs::path& trace, size_t submissions) {
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(2);
        while (std::chrono::steady_clock::now() < deadline) {
            if (fs::exists(trace) && readTrace(trace).count(RecordBody::QueueSubmit) >= submissions)
                return true;
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
        return false;
    }

    // The builds of the first `submissions` frames of a cut trace have their inputs and
    // outputs, and every snapshot's bytes read back.
    static void expectIntactBuilds(const TraceContents& t, size_t submissions) {
        ASSERT_TRUE(t.opened) << t.openError;
        EXPECT_GE(t.count(RecordBody::QueueSubmit), submissions);
        ASSERT_GE(t.buildInputs.size(), 2 * submissions);  // two builds a frame
        for (size_t b = 0; b < 2 * submissions; ++b) {
            EXPECT_FALSE(t.buildInputs[b].empty()) << "build " << b;
            EXPECT_FALSE(t.buildOutputs[b].empty()) << "build " << b;
        }
        for (const auto* lists : {&t.buildInputs, &t.buildOutputs})
            for (const auto& list : *lists)
                for (const auto& s : list) EXPECT_NE(s.bytes.front(), '<') << s.bytes;
        for (const char* code : t.damage) EXPECT_STREQ(code, "truncated");  // only the cut end
    }
};

// ---- Write failures ----------------------------------------------------------------------

TEST_F(CaptureRobustness, FullDiskAtTheStartGivesOneMessageAndServingContinues) {
    ProcessResult r = run("frames 3 --clusters 8 --out " + quote((dir / "out.json").string()),
                          {{"CLASTRACE_OUTPUT", "/dev/full"}});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(count(r.err, "clastrace:"), 1u) << r.err;
    EXPECT_EQ(count(r.err, "clastrace: capture stopped: /dev/full: "), 1u) << r.err;
    EXPECT_NE(r.err.find("No space left on device"), std::string::npos) << r.err;
    EXPECT_NE(r.out.find("frames=3"), std::string::npos) << r.out;
    // Served builds still ran: the engine wrote non-zero sizes.
    const std::string out = readText(dir / "out.json");
    EXPECT_NE(out.find("\"dstSizes\": \""), std::string::npos);
    EXPECT_EQ(out.find("\"dstSizes\": \"00000000"), std::string::npos) << out.substr(0, 80);
}

// A file size limit (SIGXFSZ ignored, so writes fail with EFBIG) stops the trace part way:
// one message naming the file and the error, the application finishes its frames, and what
// was written before the failure still reads back.
TEST_F(CaptureRobustness, WriteFailureMidTraceStopsCaptureOnceAndTheApplicationRuns) {
    const std::string limit = "ulimit -f 16; trap '' XFSZ; ";
    // Lavapipe 25 keeps device memory in a memfd, which the limit caps as well: its ftruncate
    // fails with EFBIG, unchecked, and the driver dies of SIGBUS on the mapping, capture or not.
    // There the limit cannot single out the trace's writes; the shim of
    // DiskFullMidTraceStopsCaptureOnceAndTheApplicationRuns fails them on every driver.
    if (run("frames 12 --clusters 32", {{"CLASTRACE_CAPTURE", "0"}}, limit).exitCode == -SIGBUS)
        GTEST_SKIP() << "the driver itself dies of SIGBUS under an 8 KiB file size limit (lavapipe "
                        "25's device memory is a memfd, which RLIMIT_FSIZE caps)";
    const fs::path trace = dir / "limited.clt";
    ProcessResult r =
        run("frames 12 --clusters 32",
            {{"CLASTRACE_OUTPUT", trace.string()}, {"CLASTRACE_FLUSH_MS", "5"}}, limit);
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("frames=12"), std::string::npos) << r.out;
    EXPECT_EQ(count(r.err, "clastrace:"), 1u) << r.err;
    EXPECT_EQ(count(r.err, "clastrace: capture stopped: " + trace.string() + ": offset "), 1u)
        << r.err;
    EXPECT_NE(r.err.find("File too large"), std::string::npos) << r.err;
    EXPECT_LE(fs::file_size(trace), 16u * 512);
    TraceContents t = readTrace(trace);
    ASSERT_TRUE(t.opened) << t.openError;
    EXPECT_FALSE(t.indexed);
    for (const auto& list : t.buildInputs)
        for (const auto& s : list) EXPECT_NE(s.bytes.front(), '<') << s.bytes;
}

// The disk fills up while the trace grows (writes of the trace fail with ENOSPC past 8 KiB):
// one message naming the file, the offset and the error; the application and serving go on.
TEST_F(CaptureRobustness, DiskFullMidTraceStopsCaptureOnceAndTheApplicationRuns) {
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
    GTEST_SKIP() << "an LD_PRELOAD shim cannot come before a sanitizer's runtime";
#endif
    const fs::path trace = dir / "full.clt";
    ProcessResult r = run("frames 12 --clusters 32 --out " + quote((dir / "out.json").string()),
                          {{"CLASTRACE_OUTPUT", trace.string()},
                           {"CLASTRACE_FLUSH_MS", "5"},
                           {"LD_PRELOAD", CLASTRACE_ENOSPC_SHIM},
                           {"CLASTRACE_TEST_FULL_PATH", trace.string()},
                           {"CLASTRACE_TEST_FULL_AFTER", "8192"}});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("frames=12"), std::string::npos) << r.out;
    EXPECT_EQ(count(r.err, "clastrace:"), 1u) << r.err;
    EXPECT_EQ(count(r.err, "clastrace: capture stopped: " + trace.string() + ": offset "), 1u)
        << r.err;
    EXPECT_NE(r.err.find("No space left on device"), std::string::npos) << r.err;
    EXPECT_GT(fs::file_size(trace), 0u);  // the header and what fitted were written
    EXPECT_LE(fs::file_size(trace), 8192u);
    const std::string out = readText(dir / "out.json");
    EXPECT_EQ(out.find("\"dstSizes\": \"00000000"), std::string::npos) << out.substr(0, 80);
    TraceContents t = readTrace(trace);
    ASSERT_TRUE(t.opened) << t.openError;
    for (const auto& list : t.buildInputs)
        for (const auto& s : list) EXPECT_NE(s.bytes.front(), '<') << s.bytes;
}

// ---- Applications that end abruptly -------------------------------------------------------

TEST_F(CaptureRobustness, KilledApplicationLeavesTheTraceUpToItsLastFlush) {
    const fs::path trace = dir / "killed.clt";
    pid_t pid =
        start(commandLine("frames 100000 --clusters 16 --stop-at 6",
                          {{"CLASTRACE_OUTPUT", trace.string()}, {"CLASTRACE_FLUSH_MS", "50"}}));
    ASSERT_GT(pid, 0);
    const bool reached = waitForSubmissions(trace, 6);
    kill(-pid, SIGKILL);  // the whole group: the shells, timeout and the application
    ProcessResult r = finish(pid);
    ASSERT_TRUE(reached) << "the trace never showed 6 submissions while the application ran: "
                         << r.err;
    EXPECT_EQ(r.exitCode, -SIGKILL);
    TraceContents t = readTrace(trace);
    EXPECT_FALSE(t.indexed);
    expectIntactBuilds(t, 6);
    EXPECT_FALSE(t.damage.empty());  // the reader says the file was cut
}

TEST_F(CaptureRobustness, AbortMidFrameLeavesTheTraceUpToItsLastFlush) {
    const fs::path trace = dir / "aborted.clt";
    pid_t pid =
        start(commandLine("frames 100000 --clusters 16 --abort-at 5 --wait-for " +
                              quote((dir / "go").string()),
                          {{"CLASTRACE_OUTPUT", trace.string()}, {"CLASTRACE_FLUSH_MS", "50"}}));
    ASSERT_GT(pid, 0);
    const bool reached = waitForSubmissions(trace, 5);
    std::ofstream(dir / "go") << "go";
    ProcessResult r = finish(pid);
    ASSERT_TRUE(reached) << r.err;
    EXPECT_EQ(r.exitCode, -SIGABRT) << r.err;
    TraceContents t = readTrace(trace);
    EXPECT_FALSE(t.indexed);
    expectIntactBuilds(t, 5);
}

// exit() without vkDestroyDevice while the last frame is on the queue: the layer's static
// state finishes the trace, with every frame that completed.
TEST_F(CaptureRobustness, ExitWithoutCleanupMidFrameFinishesTheTrace) {
    const fs::path trace = dir / "exited.clt";
    ProcessResult r =
        run("frames 100 --clusters 16 --exit-at 4", {{"CLASTRACE_OUTPUT", trace.string()}});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.err, "");
    TraceContents t = readTrace(trace);
    EXPECT_TRUE(t.indexed);
    expectIntactBuilds(t, 4);
    EXPECT_TRUE(t.damage.empty());
    // The frame on the queue at exit: its submission is there, and each of its builds is either
    // captured (the queue reached its pause before exit() ended the process: on a loaded machine
    // the layer's worker can win that race) or marked as not captured, never left looking like
    // a build that read nothing.
    EXPECT_EQ(t.count(RecordBody::QueueSubmit), 5u);
    ASSERT_EQ(t.buildInputs.size(), 10u);
    size_t uncaptured = 0;
    for (size_t i = 8; i < 10; ++i) uncaptured += t.buildInputs[i].empty() ? 1 : 0;
    EXPECT_EQ(t.count(RecordBody::CaptureFinding), uncaptured);
}

// ---- Host synchronization and findings -------------------------------------------------------

TEST_F(CaptureRobustness, HostSynchronizationFollowsTheSubmissionItWaitedFor) {
    const fs::path trace = dir / "sync.clt";
    ProcessResult r = run("frames 3 --clusters 4", {{"CLASTRACE_OUTPUT", trace.string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    TraceContents t = readTrace(trace);
    ASSERT_TRUE(t.opened) << t.openError;
    std::vector<RecordBody> host;  // QueueSubmit and the host calls, in trace order
    for (RecordBody k : t.kinds)
        if (k == RecordBody::QueueSubmit || k == RecordBody::HostEventOp ||
            k == RecordBody::FenceWait || k == RecordBody::FenceStatus ||
            k == RecordBody::FenceReset || k == RecordBody::QueueWaitIdle ||
            k == RecordBody::DeviceWaitIdle || k == RecordBody::HostSemaphoreOp)
            host.push_back(k);
    std::vector<RecordBody> want;
    for (int frame = 0; frame < 3; ++frame)
        for (RecordBody k :
             {RecordBody::QueueSubmit, RecordBody::HostEventOp, RecordBody::FenceWait,
              RecordBody::FenceStatus, RecordBody::FenceReset, RecordBody::HostEventOp,
              RecordBody::HostSemaphoreOp, RecordBody::HostSemaphoreOp})
            want.push_back(k);
    want.push_back(RecordBody::QueueWaitIdle);
    want.push_back(RecordBody::DeviceWaitIdle);
    EXPECT_EQ(host, want);

    // The records carry the calls' arguments and results.
    clastrace::traces::TraceError error;
    auto reader = TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    clastrace::traces::RecordView view;
    std::vector<std::string> seen;
    while (reader->next(&view)) {
        const auto* r = view.record;
        if (const auto* e = r->body_as_HostEventOp())
            seen.push_back("event op " + std::to_string(e->op()) + " result " +
                           std::to_string(e->result()));
        if (const auto* w = r->body_as_FenceWait())
            seen.push_back("fence wait " + std::to_string(w->fences()->size()) + " all " +
                           std::to_string(w->wait_all()) + " result " +
                           std::to_string(w->result()) + " timeout " +
                           std::to_string(w->timeout()));
        if (const auto* h = r->body_as_HostSemaphoreOp())
            seen.push_back("semaphore op " + std::to_string(h->op()) + " value " +
                           std::to_string(h->values()->Get(0)) + " result " +
                           std::to_string(h->result()));
    }
    ASSERT_EQ(seen.size(), 15u);
    EXPECT_EQ(seen[0], "event op 0 result 0");
    EXPECT_EQ(seen[1], "fence wait 1 all 1 result 0 timeout 60000000000");
    EXPECT_EQ(seen[2], "event op 1 result 0");
    EXPECT_EQ(seen[3], "semaphore op 0 value 1 result 0");
    EXPECT_EQ(seen[4], "semaphore op 1 value 1 result 0");
    EXPECT_EQ(seen[14], "semaphore op 1 value 3 result 0");
}

TEST_F(CaptureRobustness, ServedBuildFindingsAreRecordedAndListedByInfo) {
    const fs::path trace = dir / "findings.clt";
    ProcessResult r = run("frames 2 --clusters 4 --bad-cluster-id",
                          {{"CLASTRACE_OUTPUT", trace.string()}, {"CLASTRACE_LOG", "quiet"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    clastrace::traces::TraceError error;
    auto reader = TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    clastrace::traces::RecordView view;
    std::vector<std::tuple<std::string, uint32_t, uint64_t, uint32_t, uint8_t>> findings;
    uint64_t submissions = 0;
    while (reader->next(&view)) {
        if (view.kind == RecordBody::QueueSubmit) ++submissions;
        if (view.kind != RecordBody::CaptureFinding) continue;
        const auto* f = view.record->body_as_CaptureFinding();
        findings.emplace_back(f->rule()->str(), f->op_index(), f->submission(), f->command_index(),
                              f->severity());
        EXPECT_EQ(f->submission() + 1, submissions);  // right after the submission that ran it
    }
    // One per frame: op 0 of the triangle-cluster build (the application's third command:
    // copy, barrier, build; the layer's timestamp before the build does not count).
    const std::string rule =
        "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-clusterID-10488";
    ASSERT_EQ(findings.size(), 2u);
    for (uint64_t frame = 0; frame < 2; ++frame)
        EXPECT_EQ(findings[frame], std::make_tuple(rule, 0u, frame, 2u, uint8_t(2)));

    const std::string info = std::string(CLASTRACE_CLI) + " info " + quote(trace.string());
    const fs::path text = dir / "info.txt", json = dir / "info.json";
    std::system((info + " >" + quote(text.string()) + " 2>&1").c_str());
    std::system((info + " --json >" + quote(json.string()) + " 2>&1").c_str());
    EXPECT_EQ(count(readText(text), rule), 2u) << readText(text);
    const std::string j = readText(json);
    EXPECT_NE(j.find("\"capture_findings\""), std::string::npos) << j;
    EXPECT_EQ(count(j, rule), 2u) << j;

    // A valid scene records none.
    ProcessResult valid =
        run("frames 2 --clusters 4", {{"CLASTRACE_OUTPUT", (dir / "valid.clt").string()}});
    ASSERT_EQ(valid.exitCode, 0) << valid.err;
    EXPECT_EQ(readTrace(dir / "valid.clt").count(RecordBody::CaptureFinding), 0u);
}

// The frame loop re-records one command buffer every frame; the layer reuses its query pool and
// pause events across the recordings, so every frame's two builds still get their own valid
// pair of GPU timestamps, read back after that frame's fence, from the one pool.
TEST_F(CaptureRobustness, ReRecordedCommandBufferKeepsValidTimestampsEveryFrame) {
    const fs::path trace = dir / "timed.clt";
    ProcessResult r = run("frames 5 --clusters 4", {{"CLASTRACE_OUTPUT", trace.string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    clastrace::traces::RecordView view;
    std::vector<std::vector<const clastrace::fbs::GpuTimestamp*>> frames;
    std::set<uint64_t> pools;
    while (reader->next(&view)) {
        if (view.kind == RecordBody::CommandBufferBegin) frames.emplace_back();
        if (view.kind != RecordBody::GpuTimestamp || frames.empty()) continue;
        const auto* t = view.record->body_as_GpuTimestamp();
        frames.back().push_back(t);
        pools.insert(t->query_pool());
    }
    ASSERT_EQ(frames.size(), 5u);
    for (size_t f = 0; f < frames.size(); ++f) {
        ASSERT_EQ(frames[f].size(), 4u)
            << "frame " << f;  // before and after each of the two builds
        for (size_t i = 0; i < 4; ++i) {
            EXPECT_TRUE(frames[f][i]->ticks_valid()) << "frame " << f << " query " << i;
            EXPECT_EQ(frames[f][i]->query(), i) << "frame " << f;  // the reused pool starts over
        }
        EXPECT_GT(frames[f][1]->ticks(), frames[f][0]->ticks()) << "frame " << f;
        EXPECT_GE(frames[f][2]->ticks(), frames[f][1]->ticks()) << "frame " << f;
        if (f > 0) {
            EXPECT_GT(frames[f][0]->ticks(), frames[f - 1][3]->ticks()) << "frame " << f;
        }
    }
    EXPECT_EQ(pools.size(), 1u) << "a query pool per recording: the spare was not reused";
}

// ---- Simultaneous use and staging --------------------------------------------------------------

// Four executions of one command buffer (two in one submission): each is captured with the
// count it read, 1 for the first, 2 for the later ones (the command buffer rewrites it).
TEST_F(CaptureRobustness, SimultaneousUseCommandBufferIsCapturedPerExecution) {
    const fs::path trace = dir / "simultaneous.clt";
    ProcessResult r = run("simultaneous " + quote((dir / "out.json").string()),
                          {{"CLASTRACE_OUTPUT", trace.string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.err, "");
    TraceContents t = readTrace(trace);
    ASSERT_TRUE(t.opened) << t.openError;
    EXPECT_EQ(t.count(RecordBody::QueueSubmit), 3u);
    ASSERT_EQ(t.buildInputs.size(), 4u);
    std::vector<std::string> counts;
    for (const auto& inputs : t.buildInputs)  // srcInfosCount: the one 4-byte snapshot
        for (const auto& snapshot : inputs)
            if (snapshot.bytes.size() == 8) counts.push_back(snapshot.bytes);
    EXPECT_EQ(counts, (std::vector<std::string>{"01000000", "02000000", "02000000", "02000000"}));
    // Both clusters were built by the last execution: two non-zero sizes.
    const std::string out = readText(dir / "out.json");
    EXPECT_EQ(out.find("\"dstSizes\": \"00000000"), std::string::npos) << out;
    EXPECT_EQ(out.find("00000000\", \"counts\""), std::string::npos) << out;
}

// Device addresses differ between runs (lavapipe's are host pointers), so two runs are
// compared with every address, and every aligned 64-bit word inside the bytes that is one,
// written as "b<creation index>+<offset>" of the buffer holding it.
struct AddressNames {
    std::vector<std::tuple<uint64_t, uint64_t, size_t>> buffers;  // address, size, creation index

    explicit AddressNames(const fs::path& trace) {
        clastrace::traces::TraceError error;
        auto reader = TraceReader::open(trace.string(), &error);
        if (!reader) return;
        std::map<uint64_t, std::pair<size_t, uint64_t>> created;  // handle -> (index, size)
        clastrace::traces::RecordView view;
        while (reader->next(&view)) {
            if (const auto* c = view.record->body_as_BufferCreate())
                created[c->buffer()] = {created.size(), c->size()};
            if (const auto* b = view.record->body_as_BufferBindMemory(); b && b->device_address())
                if (auto it = created.find(b->buffer()); it != created.end())
                    buffers.emplace_back(b->device_address(), it->second.second, it->second.first);
        }
    }
    std::string name(uint64_t address) const {
        for (const auto& [at, size, index] : buffers)
            if (address >= at && address < at + size)
                return "b" + std::to_string(index) + "+" + std::to_string(address - at);
        return "";
    }
    std::string bytes(const std::string& hex) const {
        std::string out;
        for (size_t i = 0; i < hex.size(); i += 16) {
            const std::string word = hex.substr(i, 16);
            uint64_t value = 0;
            if (word.size() == 16)
                for (int b = 7; b >= 0; --b)
                    value = value << 8 | std::stoull(word.substr(2 * b, 2), nullptr, 16);
            const std::string named = word.size() == 16 ? name(value) : "";
            out += named.empty() ? word : "<" + named + ">";
        }
        return out;
    }
    // The hex strings of a JSON text, named the same way.
    std::string json(const std::string& text) const {
        std::string out, token;
        for (char c : text + '"') {
            if (c != '"') {
                token += c;
                continue;
            }
            const bool hex = token.size() >= 16 &&
                             token.find_first_not_of("0123456789abcdef") == std::string::npos;
            out += (hex ? bytes(token) : token) + '"';
            token.clear();
        }
        return out;
    }
};

// The staging path (copies into the layer's host-visible buffers before each pause, and back
// after a served build) captures and serves the very bytes of the direct path.
// Runs the frame app once per value of `variable` and expects the same application outputs and
// the same captured bytes (ranges named by buffer: the addresses may differ between runs).
void expectSameBytesForEachValue(CaptureRobustness& test, const std::string& variable,
                                 const std::vector<std::string>& values) {
    std::vector<TraceContents> traces;
    std::vector<std::string> outputs;
    std::vector<AddressNames> names;
    for (const std::string& value : values) {
        const fs::path trace = test.dir / (variable + value + ".clt");
        const fs::path out = test.dir / (variable + value + ".json");
        ProcessResult r = test.run("frames 3 --clusters 8 --out " + quote(out.string()),
                                   {{"CLASTRACE_OUTPUT", trace.string()}, {variable, value}});
        ASSERT_EQ(r.exitCode, 0) << variable << "=" << value << ": " << r.err;
        EXPECT_EQ(r.err, "") << variable << "=" << value;
        traces.push_back(readTrace(trace));
        names.emplace_back(trace);
        outputs.push_back(names.back().json(readText(out)));
        ASSERT_EQ(names.back().buffers.size(), 14u)
            << "the app's buffers, none of the layer's staging";
        ASSERT_EQ(traces.back().buildInputs.size(), 6u);
    }
    EXPECT_NE(outputs[0].find("<b"), std::string::npos);  // addresses were found and named
    // A build's snapshots by name: their order follows the buffers' handle values, which differ
    // between processes.
    auto byName = [&](size_t run, const std::vector<TraceContents::Snapshot>& list) {
        std::map<std::string, std::string> named;
        for (const auto& snapshot : list) {
            const std::string name = names[run].name(snapshot.address);
            EXPECT_NE(name, "");
            named[name] = names[run].bytes(snapshot.bytes);
        }
        return named;
    };
    for (size_t v = 1; v < values.size(); ++v) {
        const std::string which = variable + "=" + values[v] + " against " + values[0];
        EXPECT_EQ(outputs[0], outputs[v]) << which;
        for (size_t b = 0; b < 6; ++b)
            for (auto [lists, what] : {std::pair{&TraceContents::buildInputs, "inputs"},
                                       std::pair{&TraceContents::buildOutputs, "outputs"}}) {
                EXPECT_FALSE((traces[0].*lists)[b].empty());
                EXPECT_EQ(byName(0, (traces[0].*lists)[b]), byName(v, (traces[v].*lists)[b]))
                    << which << ": " << what << " of build " << b;
            }
    }
}

TEST_F(CaptureRobustness, ForcedStagingCapturesAndServesTheSameBytes) {
    expectSameBytesForEachValue(*this, "CLASTRACE_FORCE_STAGING", {"0", "1"});
}

// The injected staging copies and barriers, and a simultaneous-use command buffer run twice
// in one submission, under the Khronos validation layer with synchronization validation,
// beneath the capture layer so it sees what the driver sees.
TEST_F(CaptureRobustness, StagingAndSimultaneousUsePassSynchronizationValidation) {
    if (!fs::exists(kValidationLayerManifest))
        GTEST_SKIP() << "vulkan-validationlayers is not installed";
    std::map<std::string, std::string> env = synchronizationValidation();
    env["CLASTRACE_OUTPUT"] = (dir / "v.clt").string();
    env["CLASTRACE_FORCE_STAGING"] = "1";
    env["CLASTRACE_LOG"] = "quiet";
    for (const std::string& args : {std::string("frames 3 --clusters 4"),
                                    "simultaneous " + quote((dir / "s.json").string())}) {
        ProcessResult r = finish(start(commandLine(args, env, "", kCaptureOverValidation)));
        ASSERT_EQ(r.exitCode, 0) << args << ": " << r.err;
        const std::string all = r.out + r.err;
        EXPECT_EQ(all.find("VUID-"), std::string::npos) << args << ": " << all;
        EXPECT_EQ(all.find("SYNC-"), std::string::npos) << args << ": " << all;
        EXPECT_EQ(count(all, "Validation Error"), 0u) << args << ": " << all;
        EXPECT_GE(readTrace(dir / "v.clt").buildInputs.size(),
                  2u);  // the capture layer ran above it
    }
}

}  // namespace
