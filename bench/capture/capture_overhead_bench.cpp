// SPDX-License-Identifier: Apache-2.0
// What capturing costs an application, on lavapipe through the loader: the capture frame app
// (tests/capture/capture_frames_app) runs under VK_LAYER_CLASTRACE_capture with serving only
// (CLASTRACE_CAPTURE=0, the peer) and with capture on, and the tables give
//   1. the frame loop's wall time (best of the runs) and CPU time (median) in each mode, and
//      their ratios (goal: capture <= 1.10 x serving only),
//   2. the trace's bytes against the raw bytes its snapshots reference, and against plain zstd
//      over those bytes (the peer of dedup + zstd),
//   3. the host time per pause (median, p90) and the pause count, from the layer's report (of
//      each mode's last run),
//   4. the periodic flush knob (CLASTRACE_FLUSH_MS: what a killed application can lose) against
//      chunks, trace bytes and time,
//   5. the compression level knob (CLASTRACE_ZSTD_LEVEL) against trace bytes and time,
//   6. where capture's time went (the layer's CLASTRACE_STATS report of the last run of the
//      serving-only and capture modes).
//
//   7. the host-write watch: the default (the page guard where it works) against the hash
//      watch (CLASTRACE_HOST_WRITES=hash) and none (=0), and which mode each run had,
//   8. delta contents on against off (CLASTRACE_DELTA_CONTENTS=0): trace bytes against plain
//      zstd, and each mode's time against serving only.
//
//   9. (`pairs` only) serving only against capture, alternately: the per-pair ratios' median,
//      quartiles and range, and each ratio in run order.
//
//   capture_overhead_bench [frames=60] [clusters=256] [repetitions=5] [host-writes|deltas|pairs]
//   (host-writes: run and print only table 7; deltas: only table 8; pairs: only serving only and
//   capture, `repetitions` pairs of them, and table 9: the most pairs a given time buys)
//
// Each repetition runs every mode once; odd repetitions run them in reverse order, so a pair
// (serving only and one mode, run next to each other in a repetition) has either run first as
// often as the other, and what the first or last run of a repetition meets (a cold cache, the
// previous process's exit) falls on both sides alike.
#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/records.h>
#include <clastrace/traces/referenced_zstd.h>
#include <clastrace/traces/trace_reader.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <tuple>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;

namespace {

// The test driver (clastrace/testsupport/test_driver.h: lavapipe unless
// CLASTRACE_TEST_DRIVER_FILES says otherwise) and the build tree by default;
// CLASTRACE_BENCH_DRIVER_FILES, CLASTRACE_BENCH_LAYER_DIR and CLASTRACE_BENCH_FRAMES_APP point the
// bench at another driver and a carried bundle (the numbers in capture/README.md from a GPU
// machine were taken that way).
std::string setting(const char* variable, const char* fallback) {
    const char* v = std::getenv(variable);
    return v && *v ? v : fallback;
}

clastrace::testsupport::TestDriver bench_driver() {
    const std::string files = setting("CLASTRACE_BENCH_DRIVER_FILES", "");
    if (files.empty()) return clastrace::testsupport::test_driver();
    return {files, ""};
}

std::string readText(const fs::path& path) {
    std::ifstream in(path);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

struct Run {
    double loopMs = 0, loopCpuMs = 0;
    uint64_t pauses = 0;
    double pauseMedianMs = 0, pauseP90Ms = 0;
    std::vector<std::string> stats;  // the layer's "clastrace: stats: " lines
};

bool parseRun(const std::string& out, const std::string& err, Run& run) {
    size_t at = out.find("loop_ms=");
    if (at == std::string::npos) return false;
    run.loopMs = std::atof(out.c_str() + at + 8);
    at = out.find("loop_cpu_ms=");
    if (at != std::string::npos) run.loopCpuMs = std::atof(out.c_str() + at + 12);
    at = err.find("clastrace: pauses: ");
    if (at != std::string::npos) {
        unsigned long long count = 0;
        double median = 0, p90 = 0;
        if (std::sscanf(
                err.c_str() + at,
                "clastrace: pauses: %llu handled; host time per pause: median %lf ms, p90 %lf ms",
                &count, &median, &p90) == 3) {
            run.pauses = count;
            run.pauseMedianMs = median;
            run.pauseP90Ms = p90;
        }
    }
    std::istringstream lines(err);
    for (std::string line; std::getline(lines, line);)
        if (line.rfind("clastrace: stats: ", 0) == 0) run.stats.push_back(line.substr(18));
    return true;
}

Run runApp(const fs::path& dir, const std::string& args,
           const std::map<std::string, std::string>& env) {
    std::string line =
        "env -u CLASTRACE_OUTPUT -u CLASTRACE_CAPTURE -u CLASTRACE_DEBUG_JSON -u "
        "CLASTRACE_BACKGROUND_CPUS -u CLASTRACE_HOST_WRITES "
        "-u VK_ICD_FILENAMES";
    line += bench_driver().environment_words() + " VK_ADD_LAYER_PATH=" +
            setting("CLASTRACE_BENCH_LAYER_DIR", CLASTRACE_LAYER_MANIFEST_DIR) +
            " VK_INSTANCE_LAYERS=VK_LAYER_CLASTRACE_capture CLASTRACE_STATS=1";
    for (const auto& [k, v] : env) line += " " + k + "=" + v;
    const fs::path out = dir / "out.txt", err = dir / "err.txt";
    line += " " + setting("CLASTRACE_BENCH_FRAMES_APP", CLASTRACE_FRAMES_APP) + " " + args + " >" +
            out.string() + " 2>" + err.string();
    Run run;
    if (std::system(line.c_str()) != 0 || !parseRun(readText(out), readText(err), run)) {
        std::fprintf(stderr, "capture_overhead_bench: the app failed:\n%s\n",
                     readText(err).c_str());
        std::exit(1);
    }
    return run;
}

// Best of the runs: on a shared machine other load only ever adds time, so the minimum is the
// least disturbed measurement of each mode.
double best(const std::vector<double>& v) { return *std::min_element(v.begin(), v.end()); }
double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

// The ratios of one mode's runs to serving only's runs of the same repetitions (run next to each
// other: the VM's slow spells, which last longer than one run, move both sides of a pair alike,
// where they move the two modes' medians apart), with their spread, so one number says what the
// pairs agree on and two say how far they do.
struct PairRatios {
    std::vector<double> in_run_order;
    double median = 0, lower_quartile = 0, upper_quartile = 0, lowest = 0, highest = 0;
};

// The q-quantile of sorted `v`, interpolated between the neighbouring ranks.
double quantile(const std::vector<double>& sorted, double q) {
    const double at = q * double(sorted.size() - 1);
    const size_t below = size_t(at);
    if (below + 1 >= sorted.size()) return sorted.back();
    return sorted[below] + (at - double(below)) * (sorted[below + 1] - sorted[below]);
}

PairRatios pair_ratios(const std::vector<double>& serving, const std::vector<double>& mode) {
    PairRatios p;
    for (size_t r = 0; r < mode.size() && r < serving.size(); ++r)
        p.in_run_order.push_back(mode[r] / serving[r]);
    if (p.in_run_order.empty()) return p;
    std::vector<double> sorted = p.in_run_order;
    std::sort(sorted.begin(), sorted.end());
    p.median = quantile(sorted, 0.5);
    p.lower_quartile = quantile(sorted, 0.25);
    p.upper_quartile = quantile(sorted, 0.75);
    p.lowest = sorted.front();
    p.highest = sorted.back();
    return p;
}

// "N pairs: median M (quartiles A-B, range C-D)", and each ratio in run order, for pooling the
// pairs of several bench runs (the device's rounds) into one median.
void print_pair_ratios(const char* label, const PairRatios& p) {
    std::printf(
        "    %-29s %zu pairs: median %.3fx (quartiles %.3fx-%.3fx, range %.3fx-%.3fx); in run "
        "order:",
        label, p.in_run_order.size(), p.median, p.lower_quartile, p.upper_quartile, p.lowest,
        p.highest);
    for (double r : p.in_run_order) std::printf(" %.3f", r);
    std::printf("\n");
}

// How far the median-wall ratio could move with other runs of the same machine: the 2.5th and
// 97.5th percentiles of the ratio over resampled repetitions (rounds drawn with replacement,
// each round's two runs kept together). A fixed seed keeps the printed interval reproducible.
std::pair<double, double> bootstrapRatioInterval(const std::vector<double>& peer,
                                                 const std::vector<double>& mode) {
    std::mt19937 random(20261123);
    std::uniform_int_distribution<size_t> pick(0, peer.size() - 1);
    std::vector<double> ratios, a(peer.size()), b(peer.size());
    for (int k = 0; k < 2000; ++k) {
        for (size_t i = 0; i < peer.size(); ++i) {
            const size_t r = pick(random);
            a[i] = peer[r];
            b[i] = mode[r];
        }
        ratios.push_back(median(b) / median(a));
    }
    std::sort(ratios.begin(), ratios.end());
    return {ratios[ratios.size() * 25 / 1000], ratios[ratios.size() * 975 / 1000]};
}

struct TraceBytes {
    uint64_t fileBytes = 0, referenced = 0, stored = 0, snapshots = 0, zstdOfReferenced = 0,
             chunks = 0, deltas = 0;
};

// Counts what the trace stores, and compresses every snapshot's bytes, in trace order, with plain
// zstd at the trace's level (traces::referenced_zstd): what a capture without deduplication
// would have cost.
TraceBytes measureTrace(const fs::path& path, int zstdLevel) {
    TraceBytes t;
    t.fileBytes = fs::file_size(path);
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(path.string(), &error);
    if (!reader) {
        std::fprintf(stderr, "capture_overhead_bench: %s\n", error.message.c_str());
        std::exit(1);
    }
    clastrace::traces::RecordView view;
    while (reader->next(&view))
        if (const auto c = clastrace::traces::contents_record(*view.record)) {
            t.stored += c->size();
            if (c->delta) ++t.deltas;
        }
    t.chunks = reader->stats().chunks_read;
    clastrace::traces::ReferencedZstd peer;
    if ((error = clastrace::traces::referenced_zstd(path.string(), zstdLevel, {}, &peer))) {
        std::fprintf(stderr, "capture_overhead_bench: %s\n", error.message.c_str());
        std::exit(1);
    }
    t.snapshots = peer.snapshots;
    t.referenced = peer.referenced_bytes;
    t.zstdOfReferenced = peer.zstd_bytes;
    return t;
}

// One setting the bench runs the app under, and what its runs gave.
struct Mode {
    const char* name;
    std::map<std::string, std::string> env;
    std::vector<double> loops, cpu;
    Run last;
    TraceBytes bytes;
};

// Table 8: delta contents on (the default) against off, each trace against plain zstd of the
// bytes its snapshots reference, and each mode's frame loop against serving only.
void printDeltaTable(const Mode& serving, const Mode& deltas, const Mode& whole, int repetitions) {
    std::printf(
        "\n| delta contents                   | .clt bytes | vs plain zstd | deltas | wall ms "
        "(median) | ratio  | median pairwise | CPU ms (median) | ratio  |\n");
    std::printf(
        "|----------------------------------|-----------:|--------------:|-------:|--------------"
        ":|-------:|----------------:|----------------:|-------:|\n");
    for (const Mode* m : {&deltas, &whole}) {
        std::vector<double> pairs;
        for (int r = 0; r < repetitions; ++r) pairs.push_back(m->loops[r] / serving.loops[r]);
        const TraceBytes& b = m->bytes;
        std::printf(
            "| %-32s | %10llu | %12.3fx | %6llu | %13.1f | %5.3fx | %14.3fx | %15.1f | "
            "%5.3fx |\n",
            m == &deltas ? "on (default)" : "off (CLASTRACE_DELTA_CONTENTS=0)",
            (unsigned long long)b.fileBytes,
            b.zstdOfReferenced ? double(b.fileBytes) / double(b.zstdOfReferenced) : 0.0,
            (unsigned long long)b.deltas, median(m->loops),
            median(m->loops) / median(serving.loops), median(pairs), median(m->cpu),
            median(m->cpu) / median(serving.cpu));
    }
    std::printf(
        "(plain zstd -3 over the referenced bytes: %llu; serving only: median wall %.1f ms, "
        "CPU %.1f ms)\n",
        (unsigned long long)deltas.bytes.zstdOfReferenced, median(serving.loops),
        median(serving.cpu));
}

// The host-write watch (capture/README.md, "Host writes"): capture with the default watch (the
// page guard where mprotect works), with the hash watch, and with none, medians of the
// interleaved runs against serving only, and which mode each ran with (the layer's stats line).
void printHostWriteTable(const Mode& serving, const Mode& guard, const Mode& hash, const Mode& off,
                         int frames, int clusters) {
    std::printf(
        "\nhost-write watch, %d frames x %d clusters, %zu interleaved runs each:\n\n"
        "| capture + serving                | wall ms (median) | vs serving | vs off | pairwise "
        "vs serving | CPU ms (median) | vs off |\n"
        "|----------------------------------|-----------------:|-----------:|-------:|------------"
        "--------:|----------------:|-------:|\n",
        frames, clusters, guard.loops.size());
    const char* const labels[] = {"watch default (guard)", "watch hash (HOST_WRITES=hash)",
                                  "watch off (HOST_WRITES=0)"};
    const Mode* const rows[] = {&guard, &hash, &off};
    PairRatios pairs[3];
    for (size_t i = 0; i < 3; ++i) {
        const Mode& m = *rows[i];
        pairs[i] = pair_ratios(serving.loops, m.loops);
        std::printf("| %-32s | %16.1f | %9.3fx | %5.3fx | %18.3fx | %15.1f | %5.3fx |\n", labels[i],
                    median(m.loops), median(m.loops) / median(serving.loops),
                    median(m.loops) / median(off.loops), pairs[i].median, median(m.cpu),
                    median(m.cpu) / median(off.cpu));
    }
    std::printf(
        "(serving only: median wall %.1f ms, CPU %.1f ms)\n\nwall time against serving only, "
        "pair by pair:\n",
        median(serving.loops), median(serving.cpu));
    for (size_t i = 0; i < 3; ++i) print_pair_ratios(labels[i], pairs[i]);
    std::printf("\n");
    for (size_t i = 0; i < 3; ++i)
        for (const std::string& line : rows[i]->last.stats)
            if (line.find("host-write watch") != std::string::npos)
                std::printf("    %-29s %s\n", labels[i], line.c_str());
}

// Table 9 (`pairs`): capture against serving only, pair by pair, with the medians of each side
// and how many pairs met the goal.
void print_pairs_table(const Mode& serving, const Mode& capture, int frames, int clusters) {
    const PairRatios wall = pair_ratios(serving.loops, capture.loops);
    const PairRatios cpu = pair_ratios(serving.cpu, capture.cpu);
    const auto at_goal = std::count_if(wall.in_run_order.begin(), wall.in_run_order.end(),
                                       [](double r) { return r <= 1.10; });
    std::printf(
        "\ncapture + serving against serving only, %d frames x %d clusters, %zu pairs (alternate "
        "order):\n\n"
        "| measure | serving only (median) | capture (median) | ratio of medians | pairwise median "
        "| pairwise quartiles | pairwise range |\n"
        "|---|---:|---:|---:|---:|---:|---:|\n",
        frames, clusters, wall.in_run_order.size());
    for (const auto& [name, s, c, p] :
         {std::tuple{"wall ms", &serving.loops, &capture.loops, &wall},
          std::tuple{"CPU ms", &serving.cpu, &capture.cpu, &cpu}})
        std::printf("| %s | %.1f | %.1f | %.3fx | %.3fx | %.3fx-%.3fx | %.3fx-%.3fx |\n", name,
                    median(*s), median(*c), median(*c) / median(*s), p->median, p->lower_quartile,
                    p->upper_quartile, p->lowest, p->highest);
    std::printf("\npairs with capture <= 1.10x of serving only (wall): %lld of %zu\n",
                (long long)at_goal, wall.in_run_order.size());
    print_pair_ratios("capture + serving, wall", wall);
    print_pair_ratios("capture + serving, CPU", cpu);
    for (const std::string& line : capture.last.stats)
        if (line.rfind("host-write watch:", 0) == 0) std::printf("\n    %s\n", line.c_str());
}

// The bench's arguments: frames, clusters and repetitions, and which tables to print.
struct BenchArgs {
    int frames = 60, clusters = 256, repetitions = 5;
    bool host_writes_only = false;  // `host-writes`: only table 7
    bool deltas_only = false;       // `deltas`: only table 8
    bool pairs_only = false;        // `pairs`: only serving only and capture, table 9
};

BenchArgs parse_args(int argc, char** argv) {
    BenchArgs a;
    if (argc > 1) a.frames = std::max(1, std::atoi(argv[1]));
    if (argc > 2) a.clusters = std::clamp(std::atoi(argv[2]), 1, 4096);
    if (argc > 3) a.repetitions = std::max(1, std::atoi(argv[3]));
    const std::string only = argc > 4 ? argv[4] : "";
    a.host_writes_only = only == "host-writes";
    a.deltas_only = only == "deltas";
    a.pairs_only = only == "pairs";
    if (argc > 5 || (!only.empty() && !a.host_writes_only && !a.deltas_only && !a.pairs_only)) {
        std::fprintf(stderr,
                     "usage: capture_overhead_bench [frames] [clusters] [repetitions] "
                     "[host-writes|deltas|pairs]\n");
        std::exit(2);
    }
    return a;
}

// Indices into all_modes' list of the modes the tables name.
constexpr size_t kServing = 0, kCapture = 1, kStaging = 2, kFlush0 = 3, kFlush50 = 4, kZstd1 = 5,
                 kZstd9 = 6, kZstdMinus1 = 7, kZstdMinus5 = 8, kBackgroundApp = 9,
                 kHostWritesOff = 10, kDeltasOff = 11, kHostWritesHash = 12;

// Every mode, in the order of the indices above; each capturing mode writes `dir`/NAME.clt.
std::vector<Mode> all_modes(const fs::path& dir) {
    auto capturing = [&](const char* name, const char* file,
                         std::map<std::string, std::string> env) {
        env["CLASTRACE_OUTPUT"] = (dir / (std::string(file) + ".clt")).string();
        return Mode{name, std::move(env), {}, {}, {}, {}};
    };
    return {
        {"serving only (CLASTRACE_CAPTURE=0)", {{"CLASTRACE_CAPTURE", "0"}}, {}, {}, {}, {}},
        capturing("capture + serving", "default", {}),
        capturing("capture + serving, forced staging", "staging",
                  {{"CLASTRACE_FORCE_STAGING", "1"}}),
        capturing("capture + serving, CLASTRACE_FLUSH_MS=0", "flush0",
                  {{"CLASTRACE_FLUSH_MS", "0"}}),
        capturing("capture + serving, CLASTRACE_FLUSH_MS=50", "flush50",
                  {{"CLASTRACE_FLUSH_MS", "50"}}),
        capturing("capture + serving, CLASTRACE_ZSTD_LEVEL=1", "zstd1",
                  {{"CLASTRACE_ZSTD_LEVEL", "1"}}),
        capturing("capture + serving, CLASTRACE_ZSTD_LEVEL=9", "zstd9",
                  {{"CLASTRACE_ZSTD_LEVEL", "9"}}),
        capturing("capture + serving, CLASTRACE_ZSTD_LEVEL=-1", "zstdm1",
                  {{"CLASTRACE_ZSTD_LEVEL", "-1"}}),
        capturing("capture + serving, CLASTRACE_ZSTD_LEVEL=-5", "zstdm5",
                  {{"CLASTRACE_ZSTD_LEVEL", "-5"}}),
        capturing("capture + serving, CLASTRACE_BACKGROUND_CPUS=app", "bgapp",
                  {{"CLASTRACE_BACKGROUND_CPUS", "app"}}),
        capturing("capture + serving, CLASTRACE_HOST_WRITES=0", "nohostwrites",
                  {{"CLASTRACE_HOST_WRITES", "0"}}),
        capturing("capture + serving, CLASTRACE_DELTA_CONTENTS=0", "nodeltas",
                  {{"CLASTRACE_DELTA_CONTENTS", "0"}}),
        capturing("capture + serving, CLASTRACE_HOST_WRITES=hash", "hashwatch",
                  {{"CLASTRACE_HOST_WRITES", "hash"}}),
    };
}

// Interleaved, so drift of a shared machine spreads over every mode alike; odd repetitions in
// reverse order (the file's header says why).
void run_interleaved(std::vector<Mode>& modes, const fs::path& dir, const std::string& app_args,
                     int repetitions) {
    for (int r = 0; r < repetitions; ++r)
        for (size_t k = 0; k < modes.size(); ++k) {
            Mode& m = modes[r % 2 ? modes.size() - 1 - k : k];
            m.last = runApp(dir, app_args, m.env);
            m.loops.push_back(m.last.loopMs);
            m.cpu.push_back(m.last.loopCpuMs);
        }
}

// The trace bytes of every capturing mode's last run.
void measure_traces(std::vector<Mode>& modes) {
    for (Mode& m : modes)
        if (m.env.count("CLASTRACE_OUTPUT")) m.bytes = measureTrace(m.env["CLASTRACE_OUTPUT"], 3);
}

// Table 1: wall and CPU time of serving only, capture and forced staging, the pairwise and
// median-wall ratios and the bootstrap interval of the latter.
void print_time_table(const std::vector<Mode>& modes, const BenchArgs& a) {
    const std::string driver = bench_driver().driver_files;
    std::printf(
        "capture overhead: %d frames x (1 triangle-cluster build of %d clusters + 1 bottom-level "
        "build), "
        "%s, best of %d runs each (interleaved)\n\n",
        a.frames, a.clusters,
        driver == clastrace::testsupport::kSystemLavapipe ? "lavapipe" : driver.c_str(),
        a.repetitions);
    // Wall time is what the application feels, but on a machine shared with other work it swings
    // by tens of percent run to run; the process's CPU time (all threads: application, driver,
    // layer worker, trace writer) is the steadier measure of the work capture adds.
    const double peer = best(modes[kServing].loops), peer_cpu = median(modes[kServing].cpu);
    std::printf(
        "| mode                                  | wall ms (best) | ratio  | CPU ms (median) | "
        "ratio  |\n");
    std::printf(
        "|---------------------------------------|---------------:|-------:|----------------:|-----"
        "--:|\n");
    for (size_t i : {kServing, kCapture, kStaging}) {
        const double ms = best(modes[i].loops), cpu = median(modes[i].cpu);
        std::printf("| %-37s | %14.1f | %5.3fx | %15.1f | %5.3fx |\n", modes[i].name, ms, ms / peer,
                    cpu, cpu / peer_cpu);
    }
    // Each repetition ran serving only and capture back to back: the median of those pairs'
    // ratios is less moved by slow spells of a shared machine than the ratio of two minimums.
    const Mode &serving = modes[kServing], &capture = modes[kCapture];
    const PairRatios pairs = pair_ratios(serving.loops, capture.loops);
    const std::vector<double>& pair_wall = pairs.in_run_order;
    std::printf("| %-37s | %14s | %5.3fx | %15s | %5.3fx |\n", "capture + serving, median pairwise",
                "", pairs.median, "", pair_ratios(serving.cpu, capture.cpu).median);
    // The goal's statistic (capture/README.md): the median wall time of each mode over all runs.
    const double median_serve = median(serving.loops), median_capture = median(capture.loops);
    const auto at_goal =
        std::count_if(pair_wall.begin(), pair_wall.end(), [](double r) { return r <= 1.10; });
    std::printf("| %-37s | %14.1f | %5.3fx | %15s | %6s |\n", "capture + serving, median wall",
                median_capture, median_capture / median_serve, "", "");
    for (const std::string& line : capture.last.stats)
        if (line.rfind("host-write watch:", 0) == 0)
            std::printf("\ncapture + serving ran the %s\n", line.c_str());
    const auto [low, high] = bootstrapRatioInterval(serving.loops, capture.loops);
    std::printf(
        "\nserving only median wall %.1f ms; pairs with capture <= 1.10x: %lld of %d; median wall "
        "ratio "
        "%.3fx, 95%% bootstrap interval %.3fx-%.3fx\n",
        median_serve, (long long)at_goal, a.repetitions, median_capture / median_serve, low, high);
    print_pair_ratios("capture + serving, wall", pairs);
}

// Table 2: the default capture's trace bytes against the bytes its snapshots reference.
void print_trace_bytes_table(const TraceBytes& bytes) {
    std::printf(
        "\n| trace bytes                                    |       bytes | vs referenced |\n");
    std::printf(
        "|------------------------------------------------|------------:|--------------:|\n");
    auto row = [&](const char* name, uint64_t v) {
        std::printf("| %-46s | %11llu | %12.4fx |\n", name, (unsigned long long)v,
                    bytes.referenced ? double(v) / double(bytes.referenced) : 0.0);
    };
    std::printf("| raw bytes referenced by %6llu snapshots       | %11llu | %12.4fx |\n",
                (unsigned long long)bytes.snapshots, (unsigned long long)bytes.referenced, 1.0);
    row("after dedup (distinct contents)", bytes.stored);
    row("plain zstd -3 over the referenced bytes (peer)", bytes.zstdOfReferenced);
    row(".clt file (dedup + deltas + zstd -3)", bytes.fileBytes);
    std::printf(
        "\n.clt file = %.2fx plain zstd -3 of the referenced bytes (goal <= 1.0x); %llu of "
        "the stored contents are deltas\n",
        bytes.zstdOfReferenced ? double(bytes.fileBytes) / double(bytes.zstdOfReferenced) : 0.0,
        (unsigned long long)bytes.deltas);
}

// Table 3: host time per pause, from the layer's report of each mode's last run.
void print_pause_table(const std::vector<Mode>& modes) {
    std::printf(
        "\n| mode                                  | pauses | median ms/pause | p90 ms/pause |\n");
    std::printf(
        "|---------------------------------------|-------:|----------------:|-------------:|\n");
    for (size_t i : {kServing, kCapture, kStaging})
        std::printf("| %-37s | %6llu | %15.3f | %12.3f |\n", modes[i].name,
                    (unsigned long long)modes[i].last.pauses, modes[i].last.pauseMedianMs,
                    modes[i].last.pauseP90Ms);
}

// Table 4: the periodic flush interval against chunks, trace bytes and CPU time.
void print_flush_table(const std::vector<Mode>& modes) {
    const double peer_cpu = median(modes[kServing].cpu);
    std::printf(
        "\n| flush interval (loses at most)         | chunks | .clt bytes | CPU ms (median) | "
        "ratio vs serving only |\n");
    std::printf(
        "|----------------------------------------|-------:|-----------:|----------------:|--------"
        "--------------:|\n");
    for (size_t i : {kFlush0, kCapture, kFlush50}) {
        const Mode& m = modes[i];
        const char* label = i == kFlush0    ? "0: full 4 MiB chunks only"
                            : i == kCapture ? "1000 ms (default)"
                                            : "50 ms";
        const double cpu = median(m.cpu);
        std::printf("| %-38s | %6llu | %10llu | %15.1f | %20.3fx |\n", label,
                    (unsigned long long)m.bytes.chunks, (unsigned long long)m.bytes.fileBytes, cpu,
                    cpu / peer_cpu);
    }
}

// Table 5: compression runs on its own thread (at a lower priority than the application): the
// level trades trace bytes against that thread's CPU, which the application feels only when the
// machine has no idle core.
void print_zstd_table(const std::vector<Mode>& modes) {
    const double peer = best(modes[kServing].loops), peer_cpu = median(modes[kServing].cpu);
    std::printf(
        "\n| CLASTRACE_ZSTD_LEVEL | .clt bytes | compressor CPU ms (last run) | wall ms (best) | "
        "ratio | CPU ms (median) | ratio |\n");
    std::printf(
        "|---------------------:|-----------:|-----------------------------:|---------------:|-----"
        "-:|----------------:|------:|\n");
    for (size_t i : {kZstdMinus5, kZstdMinus1, kZstd1, kCapture, kZstd9}) {
        const Mode& m = modes[i];
        double compressor_cpu = 0;
        for (const std::string& line : m.last.stats) {
            const size_t at = line.find("compressor CPU ");
            if (at != std::string::npos) compressor_cpu = std::atof(line.c_str() + at + 15);
        }
        const double ms = best(m.loops), cpu = median(m.cpu);
        std::printf("| %20s | %10llu | %28.1f | %14.1f | %4.3fx | %15.1f | %4.3fx |\n",
                    i == kZstdMinus5   ? "-5"
                    : i == kZstdMinus1 ? "-1"
                    : i == kZstd1      ? "1"
                    : i == kCapture    ? "3 (default)"
                                       : "9",
                    (unsigned long long)m.bytes.fileBytes, compressor_cpu, ms, ms / peer, cpu,
                    cpu / peer_cpu);
    }
}

// Table 6: where the sink's and the compressor's threads run: by default on the CPUs the
// application may not use (the bench runs confined by taskset on the device), with `app` on its
// own, where their SCHED_IDLE work still shares the engine's cores and caches. Without spare CPUs
// (an unconfined run) both rows run the same placement.
void print_placement_table(const std::vector<Mode>& modes, int repetitions) {
    const Mode& serving = modes[kServing];
    const double peer = best(serving.loops), peer_cpu = median(serving.cpu);
    std::printf(
        "\n| CLASTRACE_BACKGROUND_CPUS | wall ms (best) | ratio | median wall ratio | median "
        "pairwise | CPU ms (median) | ratio |\n");
    std::printf(
        "|---------------------------|---------------:|------:|------------------:|----------------"
        ":|----------------:|------:|\n");
    for (size_t i : {kCapture, kBackgroundApp}) {
        const Mode& m = modes[i];
        std::vector<double> pairs;
        for (int r = 0; r < repetitions; ++r) pairs.push_back(m.loops[r] / serving.loops[r]);
        const double ms = best(m.loops), cpu = median(m.cpu);
        std::printf("| %-25s | %14.1f | %4.3fx | %16.3fx | %14.3fx | %15.1f | %4.3fx |\n",
                    i == kCapture ? "spare (default)" : "app", ms, ms / peer,
                    median(m.loops) / median(serving.loops), median(pairs), cpu, cpu / peer_cpu);
    }
    for (size_t i : {kCapture, kBackgroundApp})
        for (const std::string& line : modes[i].last.stats)
            if (line.rfind("background threads:", 0) == 0) std::printf("\n    %s", line.c_str());
    std::printf("\n");
}

// The layer's own account (CLASTRACE_STATS=1, capture/README.md): wall and CPU time per phase
// over the whole process, the vkDestroyDevice flush included (after the frame loop).
void print_where_time_went(const std::vector<Mode>& modes) {
    for (size_t i : {kServing, kCapture}) {
        std::printf("\nwhere the time went, %s (last run, CLASTRACE_STATS=1):\n\n", modes[i].name);
        for (const std::string& line : modes[i].last.stats) std::printf("    %s\n", line.c_str());
    }
}

// Every table, from the runs of every mode.
void print_all_tables(std::vector<Mode>& modes, const BenchArgs& a) {
    measure_traces(modes);
    print_time_table(modes, a);
    print_trace_bytes_table(modes[kCapture].bytes);
    print_pause_table(modes);
    print_flush_table(modes);
    print_zstd_table(modes);
    print_placement_table(modes, a.repetitions);
    printHostWriteTable(modes[kServing], modes[kCapture], modes[kHostWritesHash],
                        modes[kHostWritesOff], a.frames, a.clusters);
    printDeltaTable(modes[kServing], modes[kCapture], modes[kDeltasOff], a.repetitions);
    print_where_time_went(modes);
}

}  // namespace

int main(int argc, char** argv) {
    const BenchArgs a = parse_args(argc, argv);
    if (!bench_driver().installed()) {
        std::fprintf(stderr, "capture_overhead_bench: the driver manifest %s is missing (%s)\n",
                     bench_driver().driver_files.c_str(), bench_driver().missing_message().c_str());
        return 1;
    }
    const fs::path dir =
        fs::temp_directory_path() / ("clastrace_capture_bench_" + std::to_string(getpid()));
    fs::create_directories(dir);
    const std::string app_args =
        "frames " + std::to_string(a.frames) + " --clusters " + std::to_string(a.clusters);
    std::vector<Mode> modes = all_modes(dir);
    // `host-writes`: the host-write watch's table alone (guard, hash and off, with serving only
    // as the floor), for its cost without the other knobs' runs; `deltas`: table 8 alone.
    // `pairs`: serving only and capture alone, as many pairs as the repetitions say.
    if (a.host_writes_only)
        modes = {modes[kServing], modes[kCapture], modes[kHostWritesHash], modes[kHostWritesOff]};
    else if (a.deltas_only)
        modes = {modes[kServing], modes[kCapture], modes[kDeltasOff]};
    else if (a.pairs_only)
        modes = {modes[kServing], modes[kCapture]};
    run_interleaved(modes, dir, app_args, a.repetitions);
    if (a.host_writes_only) {
        printHostWriteTable(modes[0], modes[1], modes[2], modes[3], a.frames, a.clusters);
    } else if (a.pairs_only) {
        print_pairs_table(modes[0], modes[1], a.frames, a.clusters);
    } else if (a.deltas_only) {
        measure_traces(modes);
        printDeltaTable(modes[0], modes[1], modes[2], a.repetitions);
    } else {
        print_all_tables(modes, a);
    }
    fs::remove_all(dir);
    return 0;
}
