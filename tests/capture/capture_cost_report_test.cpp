// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_STATS=1: the layer's account of where capture's time went, on lavapipe through the
// loader. The counts it reports must agree with the trace it wrote (records, chunks, stored and
// deduplicated contents, submissions) and with the frames the application ran.
#include "layer_launch_test.h"
#include <clastrace/capture/background_cpus.h>
#include <clastrace/capture/layer_config.h>
#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using clastrace::fbs::RecordBody;
using clastrace::layer_launch::readText;

// The report's lines, without the "clastrace: stats: " prefix.
std::vector<std::string> statsLines(const std::string& err) {
    std::vector<std::string> lines;
    std::istringstream in(err);
    for (std::string line; std::getline(in, line);)
        if (line.rfind("clastrace: stats: ", 0) == 0) lines.push_back(line.substr(18));
    return lines;
}

// The count column of the phase line named `phase` (-1: no such line).
long long phaseCount(const std::vector<std::string>& lines, const std::string& phase) {
    for (const std::string& line : lines)
        if (line.rfind(phase + " | ", 0) == 0) return std::atoll(line.c_str() + phase.size() + 3);
    return -1;
}

struct TraceLine {
    bool found = false;
    unsigned long long records = 0, chunks = 0, raw = 0, compressed = 0, stored = 0,
                       storedBytes = 0, deduplicated = 0, deduplicatedBytes = 0;
    int level = 0;
};

TraceLine traceLine(const std::vector<std::string>& lines) {
    TraceLine t;
    for (const std::string& line : lines)
        if (std::sscanf(line.c_str(),
                        "trace: %llu records, %llu chunks, %llu raw bytes -> %llu compressed (zstd "
                        "level %d); contents: %llu "
                        "stored (%llu bytes), %llu deduplicated (%llu bytes)",
                        &t.records, &t.chunks, &t.raw, &t.compressed, &t.level, &t.stored,
                        &t.storedBytes, &t.deduplicated, &t.deduplicatedBytes) == 9)
            t.found = true;
    return t;
}

class CaptureCostReport : public clastrace::layer_launch::LayerLaunchTest {
protected:
    static constexpr int kFrames = 5;
    CaptureCostReport() : LayerLaunchTest("clastrace_cost") {}

    // Runs the frames app under the layer (behind `prefix`, e.g. a taskset); returns its stderr.
    std::string run(const std::map<std::string, std::string>& env, const std::string& prefix = "") {
        const clastrace::layer_launch::ProcessResult r =
            LayerLaunchTest::run(prefix + CLASTRACE_FRAMES_APP + " frames " +
                                     std::to_string(kFrames) + " --clusters 24",
                                 env);
        EXPECT_EQ(r.exitCode, 0) << r.err;
        return r.err;
    }
};

TEST_F(CaptureCostReport, CountsAgreeWithTheTraceWritten) {
    const fs::path trace = dir / "out.clt";
    const std::vector<std::string> lines =
        statsLines(run({{"CLASTRACE_OUTPUT", trace.string()}, {"CLASTRACE_STATS", "1"}}));
    ASSERT_FALSE(lines.empty());

    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    unsigned long long records = 0, submissions = 0, contents = 0, contentBytes = 0, snapshots = 0;
    clastrace::traces::RecordView view;
    while (reader->next(&view)) {
        ++records;
        if (view.kind == RecordBody::QueueSubmit) ++submissions;
        if (const auto c = clastrace::traces::contents_record(*view.record)) {
            ++contents;
            contentBytes += c->size();
        }
        auto lists = clastrace::traces::record_snapshots(*view.record);
        for (const auto* list : {lists.inputs, lists.outputs})
            if (list) {
                snapshots += list->size();
                // Every range the app's buffers hold is named by its buffer (and so merged with its
                // neighbours), however late the layer's threads ran.
                for (const auto* s : *list)
                    EXPECT_NE(s->buffer(), 0u) << "snapshot at 0x" << std::hex << s->address();
            }
    }
    ASSERT_TRUE(reader->damage().empty());

    // Each frame's two served builds stop the queue once each; each submission is emitted once.
    EXPECT_EQ(phaseCount(lines, "pause held (queue stalled)"), 2 * kFrames);
    EXPECT_EQ(phaseCount(lines, "served records completed"), 2 * kFrames);  // on the sink's thread
    EXPECT_EQ(phaseCount(lines, "sink: emitting submissions"), (long long)submissions);
    EXPECT_GE(submissions, (unsigned long long)kFrames);
    EXPECT_EQ(phaseCount(lines, "vkDestroyDevice flush"), 1);

    const TraceLine t = traceLine(lines);
    ASSERT_TRUE(t.found);
    EXPECT_EQ(t.records, records);
    EXPECT_EQ(t.chunks, reader->stats().chunks_read);
    EXPECT_EQ(t.level, 3);
    EXPECT_EQ(t.stored, contents);
    EXPECT_EQ(t.storedBytes, contentBytes);
    // Every snapshot's bytes were either stored or found stored already.
    EXPECT_EQ(t.stored + t.deduplicated, snapshots);
    EXPECT_GT(t.deduplicated, 0u);  // the frames repeat most of their geometry
    EXPECT_GT(t.raw, t.compressed);
}

// The watch's phase lines: one per phase of each kind of call, whose calls are the watch's calls
// and whose wall times add up to (at most) the watch's own line; the ranges the walks found are
// the ranges the mode line says were write-protected or hashed; the guard's mprotect line.
TEST_F(CaptureCostReport, HostWriteWatchPhasesAddUpToTheWatchLine) {
    const std::vector<std::string> lines = statsLines(
        run({{"CLASTRACE_OUTPUT", (dir / "phases.clt").string()}, {"CLASTRACE_STATS", "1"}}));
    double watch_ms = -1;
    long long watch_calls = -1;
    std::map<std::string, long long> calls;  // call kind -> its calls, from its phases' lines
    std::map<std::string, int> phases;       // call kind -> phase lines
    double phases_ms = 0;
    unsigned long long found = 0, guarded = 0, hashed = 0, protect_calls = 0, protected_pages = 0,
                       unprotect_calls = 0, unprotected_pages = 0;
    bool found_line = false, mprotect_line = false;
    for (const std::string& line : lines) {
        double ms = 0;
        long long n = 0;
        if (std::sscanf(line.c_str(), "host-write watch | %lld | %lf", &n, &ms) == 2) {
            watch_calls = n;
            watch_ms = ms;
        }
        const std::string phase = "host-write watch phase: ";
        if (line.rfind(phase, 0) == 0) {
            const std::string kind =
                line.substr(phase.size(), line.find(':', phase.size()) - phase.size());
            const size_t bar = line.find(" | ");
            ASSERT_NE(bar, std::string::npos) << line;
            ASSERT_EQ(std::sscanf(line.c_str() + bar, " | %lld | %lf", &n, &ms), 2) << line;
            EXPECT_TRUE(!calls.count(kind) || calls[kind] == n) << line;
            calls[kind] = n;
            ++phases[kind];
            phases_ms += ms;
        }
        if (std::sscanf(line.c_str(),
                        "host-write watch ranges found by the submissions' walks: %llu",
                        &found) == 1)
            found_line = true;
        std::sscanf(line.c_str(),
                    "host-write watch: guard: %llu ranges write-protected, %llu hashed", &guarded,
                    &hashed);
        if (std::sscanf(line.c_str(),
                        "host-write watch mprotect: read-only %llu calls, %llu pages (%*f a call), "
                        "%*f ms (%*f on CPU); writable %llu calls, %llu pages",
                        &protect_calls, &protected_pages, &unprotect_calls,
                        &unprotected_pages) == 4)
            mprotect_line = true;
    }
    ASSERT_GT(watch_calls, 0);
    // Each frame: one submission, two pauses; its waits (fence, fence status, timeline) and the
    // two idle waits after the loop.
    EXPECT_EQ(calls["submit"], kFrames);
    EXPECT_EQ(calls["pause"], 2 * kFrames);
    EXPECT_EQ(calls["wait"], 3 * kFrames + 2);
    EXPECT_EQ(calls["submit"] + calls["pause"] + calls["wait"], watch_calls);
    EXPECT_EQ(phases["submit"], 7);  // lock wait, looks, walks, resolve, guard, hash, kept
    EXPECT_EQ(phases["pause"], 2);
    EXPECT_EQ(phases["wait"], 3);
    EXPECT_GT(phases_ms, 0.0);
    EXPECT_LE(phases_ms, watch_ms + 0.001 * 12);  // each line rounds to a microsecond
    ASSERT_TRUE(found_line);
    EXPECT_GT(found, 0u);
    EXPECT_EQ(found, guarded + hashed);
    ASSERT_TRUE(mprotect_line);
    EXPECT_GT(protect_calls, 0u);
    EXPECT_GE(protected_pages, protect_calls);
    // Pages unwritten when their watchers go stay read-only (page_guard.h): only the probes' and
    // freed memory's pages are made writable by mprotect.
    EXPECT_LE(unprotected_pages, protected_pages);
    EXPECT_GE(unprotect_calls, 1u);
}

TEST_F(CaptureCostReport, ServingOnlyReportsThePausesAndNoTrace) {
    const std::vector<std::string> lines =
        statsLines(run({{"CLASTRACE_CAPTURE", "0"}, {"CLASTRACE_STATS", "1"}}));
    EXPECT_EQ(phaseCount(lines, "pause held (queue stalled)"), 2 * kFrames);
    EXPECT_EQ(phaseCount(lines, "  engine (served build)"), 2 * kFrames);
    EXPECT_EQ(phaseCount(lines, "  reading inputs/outputs"), -1);
    EXPECT_EQ(phaseCount(lines, "sink: emitting submissions"), -1);
    EXPECT_FALSE(traceLine(lines).found);
}

// One read feeds both: the capture's walk of a served build's inputs reads through the engine's
// image, so each reached buffer is copied from the application's memory once a pause, with
// capture on or off, and the copies are counted apart from the reading and the engine.
TEST_F(CaptureCostReport, ServedBuffersAreCopiedOnceAPauseWithCaptureOrWithout) {
    const std::string copied = "  buffers copied into the engine's image";
    const long long serving =
        phaseCount(statsLines(run({{"CLASTRACE_CAPTURE", "0"}, {"CLASTRACE_STATS", "1"}})), copied);
    const long long capturing =
        phaseCount(statsLines(run({{"CLASTRACE_OUTPUT", (dir / "copies.clt").string()},
                                   {"CLASTRACE_STATS", "1"}})),
                   copied);
    EXPECT_GE(serving, 2 * kFrames);  // at least a buffer a build
    EXPECT_EQ(capturing, serving);
}

TEST_F(CaptureCostReport, NoReportUnlessAsked) {
    EXPECT_TRUE(statsLines(run({{"CLASTRACE_OUTPUT", (dir / "quiet.clt").string()}})).empty());
}

TEST(CaptureCostSetting, ParsesAndRejectsByName) {
    auto parse = [](const char* value) {
        return clastrace::capture::parse_layer_config([value](const char* name) -> const char* {
            return std::string(name) == "CLASTRACE_STATS" ? value : nullptr;
        });
    };
    EXPECT_FALSE(parse(nullptr).stats);
    EXPECT_TRUE(parse("1").stats);
    EXPECT_FALSE(parse("0").stats);
    const auto bad = parse("sometimes");
    EXPECT_FALSE(bad.stats);
    ASSERT_EQ(bad.errors.size(), 1u);
    EXPECT_NE(bad.errors[0].find("CLASTRACE_STATS='sometimes'"), std::string::npos);
}

// CLASTRACE_BACKGROUND_CPUS with the application confined to CPU 0: by default (spare) the
// sink's and the compressor's threads leave it; `app` keeps them there; a list is obeyed. The
// line reads back what the kernel gave the sink's thread, not what was asked.
TEST_F(CaptureCostReport, BackgroundThreadsGoWhereTheSettingSays) {
    const std::vector<unsigned> online = clastrace::capture::online_cpus();
    if (online.size() < 2 || online[0] != 0) GTEST_SKIP() << "needs CPU 0 and another online CPU";
    // Spare: the others, less CPU 0's SMT siblings where the machine has other cores.
    const std::vector<unsigned> siblings = clastrace::capture::smt_siblings({0});
    const std::string others = clastrace::capture::format_cpu_list(
        clastrace::capture::background_cpus_for({}, online, {0}, {}, siblings));
    const std::string application =
        siblings.empty()
            ? "0"
            : "0; their SMT siblings: " + clastrace::capture::format_cpu_list(siblings);
    const std::string last = std::to_string(online.back());
    auto placementLine = [&](const char* setting) {
        std::map<std::string, std::string> env{{"CLASTRACE_OUTPUT", (dir / "placed.clt").string()},
                                               {"CLASTRACE_STATS", "1"}};
        if (setting) env["CLASTRACE_BACKGROUND_CPUS"] = setting;
        for (const std::string& line : statsLines(run(env, "taskset -c 0 ")))
            if (line.rfind("background threads: ", 0) == 0) return line;
        return std::string("(no placement line)");
    };
    const std::string spare = "background threads: asked for CPUs " + others +
                              " (the application's: " + application + "); sink on " + others +
                              ", compressor placed";
    EXPECT_EQ(placementLine(nullptr), spare);
    EXPECT_EQ(placementLine("spare"), spare);
    EXPECT_EQ(
        placementLine("app"),
        "background threads: with the application (CPUs 0); sink on 0, compressor as created");
    EXPECT_EQ(placementLine(last.c_str()), "background threads: asked for CPUs " + last +
                                               " (the application's: " + application +
                                               "); sink on " + last + ", compressor placed");
    // A CPU the kernel refuses (none such here; a cpuset would do the same): both threads stay
    // with the application and the line says so.
    if (online.back() < 4095) {
        EXPECT_EQ(placementLine("4095"),
                  "background threads: asked for CPUs 4095 (the application's: " + application +
                      "); sink on 0, compressor refused (as created)");
    }
}

// `clastrace capture --background-cpus` passes the setting to the layer, and a malformed value
// stops before the application runs, naming the option.
TEST_F(CaptureCostReport, CaptureCommandSetsTheBackgroundCpusAndRejectsABadValue) {
    const std::string trace = (dir / "cli.clt").string();
    const std::string app = std::string(CLASTRACE_FRAMES_APP) + " frames 2 --clusters 8";
    clastrace::layer_launch::ProcessResult r =
        LayerLaunchTest::run(std::string(CLASTRACE_CLI) + " capture -o " + trace +
                                 " --background-cpus app -- " + app,
                             {{"CLASTRACE_STATS", "1"}}, false);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("clastrace: stats: background threads: with the application"),
              std::string::npos)
        << r.err;
    for (const char* bad : {"3-1", "x", "1,", "4096", "idle"}) {
        clastrace::layer_launch::ProcessResult b =
            LayerLaunchTest::run(std::string(CLASTRACE_CLI) + " capture -o " + trace +
                                     " --background-cpus " + bad + " -- " + app,
                                 {}, false);
        EXPECT_EQ(b.exitCode, 2) << bad;
        EXPECT_NE(b.err.find(std::string("--background-cpus: '") + bad +
                             "' is not spare, app or a CPU list"),
                  std::string::npos)
            << b.err;
        EXPECT_EQ(b.out.find("frames="), std::string::npos)
            << "the application ran despite --background-cpus " << bad;
    }
}

}  // namespace
