// SPDX-License-Identifier: Apache-2.0
// replay_throughput_bench [--ops N] [--max-ops M] [--dir D] [--threads T] [--repeat R] | --write-trace PATH OPS
// | --child-replay PATH THREADS | --replay-once PATH hazards|no-hazards [THREADS]: replay throughput on one and on T threads, next to the engine
// alone and plain zstd decompression of the same trace, then how replay time and peak memory
// grow with trace length.
//
// Table 1 replays one generated trace of N ops (default 10^5): on one thread with hazard
// checking and without (--no-hazards), on T threads (default: the machine's cores) with
// hazard checking (the sync model inline, each command in its turn: RUN_AHEAD=0), with the
// sync model on its own thread (CLASTRACE_REPLAY_SYNC_THREAD=1), and with cluster builds run
// ahead of their turn (CLASTRACE_REPLAY_RUN_AHEAD=1, docs/replay.md "Threads"), and with both;
// each replay in a process of its own (--replay-once), the settings interleaved round by round,
// R rounds (--repeat R, default 7), every column the median of the R. Then the engine alone: the
// wall time of every engine::execute call inside those one-thread replays
// (ReplayedCommand::engine_ns, summed by an observer), i.e. exactly the ops the replay ran; and
// the peer: read the file and ZSTD_decompress each chunk, nothing else. A one-thread replay is
// divided by its own run's engine time, a T-thread one (run without the observer, which would
// drain the sync model's queue each command) by its round's one-thread hazards-on run's: on a
// noisy host the engine's time moves by 30% between runs, and a run's replay with it. The T-thread
// rows also say the replay thread's CPU time (getrusage RUSAGE_THREAD on the thread that calls
// replay_trace), over the wall: the serial share the other threads cannot take. Goals (issue 23):
// replay (one thread) <= 1.1x the engine alone, hazards on <= 1.2x hazards off, T threads >= 8x
// one thread on 16 cores at 10^6 ops.
//
// Table 2 replays traces of 10^2 .. M ops (default 10^6) on T threads, each in a fresh child
// process, so its peak RSS is that size's alone; beside it the largest submission's bytes (its
// records plus the memory snapshots it carries) and the largest record chunk's decompressed bytes.
// Goal: peak memory bounded by the largest submission, not the trace length. What it is bounded
// by today is the reader's chunk buffers (a few chunks' raw bytes) and the replay's working set;
// docs/benchmarks.md has the heap profile.
#include "chunk_streams.h"
#include "replay_bench_trace.h"

#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>


#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>
#include <zstd.h>

using namespace clastrace;

namespace {

double now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

// CPU seconds of the whole process (all threads): steadier than wall time on a busy machine.
double cpu_now() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// The high-water mark of this process image's memory (VmHWM). Not getrusage's ru_maxrss,
// which a child keeps from its parent across fork and exec.
// CPU seconds of the calling thread alone: in a replay, the replay thread's (replay_trace runs on
// its caller), whose share of the run is the serial part the other threads cannot take.
double thread_cpu_now() {
    rusage u{};
    getrusage(RUSAGE_THREAD, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

uint64_t peak_rss_kb() {
    FILE* f = std::fopen("/proc/self/status", "r");
    if (!f) return 0;
    char line[256];
    unsigned long long kb = 0;
    while (std::fgets(line, sizeof line, f))
        if (std::sscanf(line, "VmHWM: %llu kB", &kb) == 1) break;
    std::fclose(f);
    return kb;
}

uint64_t current_rss_kb() {
    FILE* f = std::fopen("/proc/self/statm", "r");
    if (!f) return 0;
    unsigned long pages = 0, resident = 0;
    if (std::fscanf(f, "%lu %lu", &pages, &resident) != 2) resident = 0;
    std::fclose(f);
    return uint64_t(resident) * uint64_t(sysconf(_SC_PAGESIZE)) / 1024;
}

struct ReplayRun {
    double seconds = 0;
    double cpu = 0;
    double replay_thread_cpu = 0;
    replay::ReplayReport report;
    uint64_t raw_bytes = 0;
};

// Sums the time the engine spent in engine::execute (and the NV/KHR builds) during a replay.
struct EngineTime : replay::ReplayObserver {
    uint64_t ns = 0;
    uint64_t commands = 0;
    void on_command(const replay::ReplayedCommand& command) override {
        if (command.engine_ns == 0) return;
        ns += command.engine_ns;
        ++commands;
    }
};

ReplayRun replay_once(const std::string& path, bool hazards, uint32_t threads,
                      replay::ReplayObserver* observer = nullptr,
                      replay::ReplayOptions::RunAheadCounts* run_ahead = nullptr) {
    ReplayRun run;
    traces::TraceError error;
    const double t0 = now(), c0 = cpu_now(), r0 = thread_cpu_now();
    auto reader = traces::TraceReader::open(path, &error);
    if (!reader) {
        std::fprintf(stderr, "cannot open %s: %s\n", path.c_str(), error.message.c_str());
        std::exit(1);
    }
    replay::ReplayOptions options;
    options.check_hazards = hazards;
    options.threads = threads;
    options.observer = observer;
    options.run_ahead_counts = run_ahead;
    run.report = replay::replay_trace(*reader, path, options);
    run.seconds = now() - t0;
    run.cpu = cpu_now() - c0;
    run.replay_thread_cpu = thread_cpu_now() - r0;
    run.raw_bytes = reader->stats().raw_bytes;
    return run;
}

// The peer: every records chunk read from the file and decompressed, nothing else.
struct ZstdRun {
    double seconds = 0;
    double cpu = 0;
    uint64_t raw_bytes = 0;
    uint64_t chunks = 0;
};

// The trace's chunks as the file lays them out (docs/trace-format.md): a 32-byte file header and
// its padded header table, then per chunk a 48-byte header and its compressed payload.
struct ChunkHeader {
    uint16_t kind = 0;  // 1: records; the index chunk is another kind
    uint32_t raw_size = 0, compressed_size = 0;
};

FILE* open_chunks(const std::string& path) {
    FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) std::exit(1);
    uint8_t file_header[32];
    if (std::fread(file_header, 1, 32, f) != 32) std::exit(1);
    uint32_t header_size = 0;
    std::memcpy(&header_size, file_header + 12, 4);
    std::fseek(f, long(32 + ((header_size + 7) / 8) * 8), SEEK_SET);
    return f;
}

// Reads the next chunk's header; the file is then at its payload.
bool next_chunk(FILE* f, ChunkHeader* chunk) {
    uint8_t h[48];
    if (std::fread(h, 1, 48, f) != 48 || std::memcmp(h, "CLCK", 4) != 0) return false;
    std::memcpy(&chunk->kind, h + 4, 2);
    std::memcpy(&chunk->raw_size, h + 16, 4);
    std::memcpy(&chunk->compressed_size, h + 20, 4);
    return true;
}

ZstdRun zstd_once(const std::string& path) {
    ZstdRun run;
    const double t0 = now(), c0 = cpu_now();
    FILE* f = open_chunks(path);
    ZSTD_DCtx* dctx = ZSTD_createDCtx();
    std::vector<uint8_t> payload, raw;
    ChunkHeader h;
    while (next_chunk(f, &h)) {
        payload.resize(h.compressed_size);
        if (std::fread(payload.data(), 1, h.compressed_size, f) != h.compressed_size) break;
        if (h.kind != 1) continue;  // the index chunk: the replay does not decompress it either
        raw.resize(h.raw_size);
        // A streams payload (records and contents in two frames) is zstd's work too.
        size_t n = h.raw_size;
        if (!traces::format::is_streams_payload(payload.data(), payload.size()))
            n = ZSTD_decompressDCtx(dctx, raw.data(), raw.size(), payload.data(), payload.size());
        else if (traces::format::decode_streams_payload(dctx, payload.data(), payload.size(),
                                                        raw.data(), raw.size()))
            n = 0;  // "size differs" below
        if (ZSTD_isError(n) || n != h.raw_size) {
            std::fprintf(stderr, "zstd: %s\n", ZSTD_getErrorName(n));
            std::exit(1);
        }
        run.raw_bytes += n;
        ++run.chunks;
    }
    ZSTD_freeDCtx(dctx);
    std::fclose(f);
    run.seconds = now() - t0;
    run.cpu = cpu_now() - c0;
    return run;
}

// The largest record chunk's decompressed bytes: the unit of the reader's buffers (the chunk
// being read, the one read ahead, and the chunk a content is read from).
uint64_t largest_raw_chunk(const std::string& path) {
    FILE* f = open_chunks(path);
    uint64_t largest = 0;
    ChunkHeader h;
    while (next_chunk(f, &h)) {
        if (h.kind == 1) largest = std::max<uint64_t>(largest, h.raw_size);
        if (std::fseek(f, long(h.compressed_size), SEEK_CUR) != 0) break;
    }
    std::fclose(f);
    return largest;
}

void require_clean(const replay::ReplayReport& r, const char* what) {
    if (r.clean()) return;
    std::fprintf(stderr, "warning: %s replay is not clean: %zu findings, %zu hazards, %zu damage\n",
                 what, r.findings.size(), r.hazards.size(), r.trace_damage.size());
    if (!r.findings.empty())
        std::fprintf(stderr, "  first finding: %s\n", r.findings[0].format().c_str());
    if (!r.hazards.empty())
        std::fprintf(stderr, "  first hazard: %s\n", r.hazards[0].format().c_str());
}

std::string trace_path(const std::string& dir, uint64_t ops) {
    return dir + "/replay_bench_" + std::to_string(ops) + "_" + std::to_string(getpid()) + ".clt";
}

// Child: replays with hazard checking and prints one line for the parent.
int child_replay(const std::string& path, uint32_t threads) {
    const uint64_t base = current_rss_kb();
    ReplayRun run = replay_once(path, true, threads);
    require_clean(run.report, "child");
    std::printf("RESULT %.6f %llu %llu %llu %llu\n", run.seconds, (unsigned long long)peak_rss_kb(),
                (unsigned long long)base, (unsigned long long)run.report.counts.peak_image_bytes,
                (unsigned long long)run.report.counts.commands);
    return 0;
}

// One one-thread replay of a kept trace (--write-trace), with or without the hazard model, and
// the engine's share of it: the run to put under callgrind or perf, where the difference of two
// runs' instruction counts is the hazard model's cost and the rest beyond engine::execute the
// replay's own.
// With THREADS > 1 (and CLASTRACE_REPLAY_RUN_AHEAD / CLASTRACE_REPLAY_SYNC_THREAD as wanted),
// `valgrind --tool=callgrind --separate-threads=yes` then counts the instructions the replay
// thread runs apart from the others': its serial share (docs/benchmarks.md, issue 23).
int replay_once_for_profiler(const std::string& path, bool hazards, uint32_t threads) {
    EngineTime engine;
    replay::ReplayOptions::RunAheadCounts run_ahead;
    ReplayRun run =
        replay_once(path, hazards, threads, threads == 1 ? &engine : nullptr, &run_ahead);
    require_clean(run.report, "profiled");
    std::printf(
        "%s: %llu ops, hazards %s, %u thread(s), %.3f s, engine %.3f s (1 thread only), %zu "
        "hazards; runs ahead started %llu, stood %llu, run again %llu\n",
        path.c_str(), (unsigned long long)run.report.counts.cluster_ops, hazards ? "on" : "off",
        threads, run.seconds, 1e-9 * double(engine.ns), run.report.hazards.size(),
        (unsigned long long)run_ahead.started, (unsigned long long)run_ahead.stood,
        (unsigned long long)run_ahead.run_again);
    // For table 1, which runs this in a child process per replay (OnceResult).
    const replay::ReplayCounts& n = run.report.counts;
    std::printf("RESULT %.6f %.6f %.6f %.6f %llu %llu %llu %llu %llu %llu %llu %llu %llu %zu\n",
                run.seconds, run.cpu, run.replay_thread_cpu, 1e-9 * double(engine.ns),
                (unsigned long long)n.commands, (unsigned long long)engine.commands,
                (unsigned long long)run.raw_bytes, (unsigned long long)n.snapshot_bytes,
                (unsigned long long)n.accesses, (unsigned long long)run_ahead.started,
                (unsigned long long)run_ahead.stood, (unsigned long long)run_ahead.run_again,
                (unsigned long long)peak_rss_kb(),
                std::hash<std::string>{}(replay::to_json(run.report).dump()));
    return 0;
}

// Runs this program again with `args`; what it printed after "RESULT ", or empty when it failed
// (its stderr is ours).
std::string run_self(const std::vector<std::string>& args) {
    int fds[2];
    if (pipe(fds) != 0) return {};
    pid_t pid = fork();
    if (pid == 0) {
        dup2(fds[1], 1);
        close(fds[0]);
        close(fds[1]);
        std::vector<char*> argv{const_cast<char*>("/proc/self/exe")};
        for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        execv(argv[0], argv.data());
        _exit(127);
    }
    close(fds[1]);
    std::string out;
    char buf[512];
    ssize_t n;
    while ((n = read(fds[0], buf, sizeof buf)) > 0) out.append(buf, size_t(n));
    close(fds[0]);
    int status = 0;
    waitpid(pid, &status, 0);
    const size_t at = out.find("RESULT ");
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || at == std::string::npos) return {};
    return out.substr(at + 7);
}

struct ChildResult {
    double seconds = 0;
    uint64_t peak_kb = 0, base_kb = 0, image_peak = 0, commands = 0;
    bool ok = false;
};

ChildResult run_child(const std::string& path, uint32_t threads) {
    ChildResult r;
    const std::string out = run_self({"--child-replay", path, std::to_string(threads)});
    unsigned long long peak = 0, base = 0, image = 0, commands = 0;
    if (std::sscanf(out.c_str(), "%lf %llu %llu %llu %llu", &r.seconds, &peak, &base, &image,
                    &commands) == 5) {
        r.peak_kb = peak;
        r.base_kb = base;
        r.image_peak = image;
        r.commands = commands;
        r.ok = true;
    }
    return r;
}

// What one `--replay-once` process printed (replay_once_for_profiler).
struct OnceResult {
    double wall = 0, cpu = 0, replay_thread_cpu = 0, engine = 0;  // engine: 1 thread only
    unsigned long long commands = 0, engine_calls = 0, raw_bytes = 0, snapshot_bytes = 0,
                       accesses = 0, started = 0, stood = 0, run_again = 0, peak_kb = 0;
    size_t report_hash = 0;
    bool ok = false;
};

// Sets CLASTRACE_REPLAY_* variable `name` to `value`, or unsets it for null.
void set_or_unset(const char* name, const char* value) {
    if (value)
        setenv(name, value, 1);
    else
        unsetenv(name);
}

// One replay in a fresh process, under the run-ahead and sync-thread settings given.
OnceResult replay_in_child(const std::string& path, bool hazards, uint32_t threads,
                           const char* run_ahead, const char* sync_thread) {
    set_or_unset("CLASTRACE_REPLAY_RUN_AHEAD", run_ahead);
    set_or_unset("CLASTRACE_REPLAY_SYNC_THREAD", sync_thread);
    const std::string out = run_self(
        {"--replay-once", path, hazards ? "hazards" : "no-hazards", std::to_string(threads)});
    OnceResult r;
    r.ok =
        std::sscanf(out.c_str(), "%lf %lf %lf %lf %llu %llu %llu %llu %llu %llu %llu %llu %llu %zu",
                    &r.wall, &r.cpu, &r.replay_thread_cpu, &r.engine, &r.commands, &r.engine_calls,
                    &r.raw_bytes, &r.snapshot_bytes, &r.accesses, &r.started, &r.stood,
                    &r.run_again, &r.peak_kb, &r.report_hash) == 14;
    if (!r.ok) {
        std::fprintf(stderr, "replay of %s in a child process failed\n", path.c_str());
        std::exit(1);
    }
    return r;
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const size_t n = v.size();
    return n == 0 ? 0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// The median over the rounds of f(round).
template <class F>
double median_over(size_t rounds, F&& f) {
    std::vector<double> v;
    for (size_t i = 0; i < rounds; ++i) v.push_back(f(i));
    return median(v);
}

double mb(uint64_t bytes) { return double(bytes) / 1e6; }

// One row of table 1: a replay setting and its runs, one per round.
struct Setting {
    std::string name;
    bool hazards = true;
    bool many = false;                  // T threads, else 1
    const char* run_ahead = nullptr;    // CLASTRACE_REPLAY_RUN_AHEAD, null: unset
    const char* sync_thread = nullptr;  // CLASTRACE_REPLAY_SYNC_THREAD, null: unset
    std::vector<OnceResult> runs;
};

// Table 1's rows, in the order they run each round and print.
enum SettingRow : size_t { kOneThreadOn, kOneThreadOff, kInTurn, kSyncThread, kRunAhead, kBoth };

std::vector<Setting> throughput_settings(uint32_t threads) {
    const std::string t = std::to_string(threads) + " threads, hazards on, ";
    return {
        {"replay, 1 thread, hazards on", true, false, nullptr, nullptr, {}},
        {"replay, 1 thread, hazards off (--no-hazards)", false, false, nullptr, nullptr, {}},
        {"replay, " + t + "every build in its turn (CLASTRACE_REPLAY_RUN_AHEAD=0)",
         true,
         true,
         "0",
         nullptr,
         {}},
        {"replay, " + t +
             "sync model on its own thread (CLASTRACE_REPLAY_SYNC_THREAD=1, RUN_AHEAD=0)",
         true,
         true,
         "0",
         "1",
         {}},
        {"replay, " + t + "cluster builds run ahead (CLASTRACE_REPLAY_RUN_AHEAD=1)",
         true,
         true,
         "1",
         nullptr,
         {}},
        {"replay, " + t + "the model's thread and runs ahead (both =1)", true, true, "1", "1", {}},
    };
}

// Table 1's measurements: every setting's runs and the zstd peer's, round by round.
struct ThroughputRounds {
    bench::BenchTraceStats stats;
    uint32_t threads = 0;
    size_t rounds = 0;
    std::vector<Setting> settings;
    std::vector<ZstdRun> zstd;
    double raw_mb = 0;          // the trace decompressed (the last one-thread run's count)
    double engine_seconds = 0;  // median of the one-thread runs' engine times

    const Setting& row(SettingRow r) const { return settings[r]; }
    // The median over the rounds of field(run, round) for setting `s`.
    template <class F>
    double median_of(const Setting& s, F&& field) const {
        return median_over(rounds, [&](size_t i) { return field(s.runs[i], i); });
    }
    // The engine time a run is divided by: a one-thread run's own; a T-thread run (no observer
    // there: it would drain the model's queue every command) the same round's one-thread
    // hazards-on run's.
    double engine_of(const Setting& s, size_t i) const {
        return s.many ? row(kOneThreadOn).runs[i].engine : s.runs[i].engine;
    }
    double zstd_median(double ZstdRun::*field) const {
        return median_over(rounds, [&](size_t i) { return zstd[i].*field; });
    }
};

// Runs the rounds: zstd, then each setting in its own process. The caller's
// CLASTRACE_REPLAY_RUN_AHEAD and CLASTRACE_REPLAY_SYNC_THREAD are set back after (table 2
// runs with them).
void run_rounds(const std::string& path, int repeats, ThroughputRounds& t) {
    const char* asked_run_ahead = std::getenv("CLASTRACE_REPLAY_RUN_AHEAD");
    const char* asked_sync = std::getenv("CLASTRACE_REPLAY_SYNC_THREAD");
    const std::string kept_run_ahead = asked_run_ahead ? asked_run_ahead : "";
    const std::string kept_sync = asked_sync ? asked_sync : "";
    for (int rep = 0; rep < repeats; ++rep) {
        t.zstd.push_back(zstd_once(path));
        for (Setting& s : t.settings)
            s.runs.push_back(replay_in_child(path, s.hazards, s.many ? t.threads : 1, s.run_ahead,
                                             s.sync_thread));
    }
    set_or_unset("CLASTRACE_REPLAY_RUN_AHEAD", asked_run_ahead ? kept_run_ahead.c_str() : nullptr);
    set_or_unset("CLASTRACE_REPLAY_SYNC_THREAD", asked_sync ? kept_sync.c_str() : nullptr);
    t.rounds = size_t(repeats);
}

// The T-thread report (in turn) must be the one-thread one's, round by round.
void warn_if_reports_differ(const ThroughputRounds& t) {
    for (size_t i = 0; i < t.rounds; ++i)
        if (t.row(kInTurn).runs[i].report_hash != t.row(kOneThreadOn).runs[i].report_hash)
            std::fprintf(stderr,
                         "warning: the %u-thread report differs from the one-thread one (round "
                         "%zu)\n",
                         t.threads, i + 1);
}

double median_engine_seconds(const ThroughputRounds& t) {
    std::vector<double> engine_times;
    for (size_t i = 0; i < t.rounds; ++i) {
        engine_times.push_back(t.row(kOneThreadOn).runs[i].engine);
        engine_times.push_back(t.row(kOneThreadOff).runs[i].engine);
    }
    return median(engine_times);
}

void print_throughput_heading(const ThroughputRounds& t, int repeats) {
    const OnceResult& last = t.row(kOneThreadOn).runs.back();
    std::printf(
        "replay throughput, %llu ops (%llu cluster ops, %llu commands, %llu engine calls, %llu "
        "submissions), trace %.2f MB on disk, %.2f MB decompressed, %.2f MB of memory laid in. "
        "Each replay in its own process (--replay-once), %d rounds interleaved (zstd, then the "
        "rows in order); medians of the %d rounds. Ratios: each run over its own engine time "
        "(engine::execute summed; a %u-thread run: its round's 1-thread hazards-on run's), then "
        "the "
        "median\n",
        (unsigned long long)t.stats.ops, (unsigned long long)t.stats.cluster_ops,
        (unsigned long long)last.commands, (unsigned long long)last.engine_calls,
        (unsigned long long)t.stats.submissions, mb(t.stats.file_bytes), t.raw_mb,
        mb(last.snapshot_bytes), repeats, repeats, t.threads);
    std::printf(
        "| run | wall s | CPU s (all threads) | replay thread CPU s (of wall) | ops/s (wall) | "
        "trace MB/s (decompressed, wall) | wall / engine | CPU / engine | wall vs zstd |\n");
    std::printf("|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
}

void print_setting_row(const ThroughputRounds& t, const Setting& s) {
    const double wall = t.median_of(s, [](const OnceResult& r, size_t) { return r.wall; });
    const double cpu = t.median_of(s, [](const OnceResult& r, size_t) { return r.cpu; });
    const double serial =
        t.median_of(s, [](const OnceResult& r, size_t) { return r.replay_thread_cpu; });
    const double share =
        t.median_of(s, [](const OnceResult& r, size_t) { return r.replay_thread_cpu / r.wall; });
    std::printf(
        "| %s | %.4f | %.4f | %.4f (%.0f%%) | %.0f | %.1f | %.3fx | %.3fx | %.1fx |\n",
        s.name.c_str(), wall, cpu, serial, 100 * share, double(t.stats.ops) / wall, t.raw_mb / wall,
        t.median_of(s, [&](const OnceResult& r, size_t i) { return r.wall / t.engine_of(s, i); }),
        t.median_of(s, [&](const OnceResult& r, size_t i) { return r.cpu / t.engine_of(s, i); }),
        t.median_of(s, [&](const OnceResult& r, size_t i) { return r.wall / t.zstd[i].seconds; }));
}

// The two peers' rows: the engine alone and zstd alone.
void print_peer_rows(const ThroughputRounds& t) {
    const double engine = t.engine_seconds, zstd = t.zstd_median(&ZstdRun::seconds);
    std::printf(
        "| engine alone: engine::execute of the same ops (1 thread, summed in those runs) "
        "| %.4f | %.4f | - | %.0f | %.1f | 1.000x | 1.000x | %.1fx |\n",
        engine, engine, double(t.stats.ops) / engine, t.raw_mb / engine, engine / zstd);
    std::printf(
        "| zstd: read + ZSTD_decompress each chunk (%llu chunks) | %.4f | %.4f | - | %.0f "
        "| %.1f | - | - | 1.0x |\n",
        (unsigned long long)t.zstd.back().chunks, zstd, t.zstd_median(&ZstdRun::cpu),
        double(t.stats.ops) / zstd, t.raw_mb / zstd);
}

// The goals' ratios, the T-thread speedups and serial shares, and the runs' counters.
void print_throughput_summary(const ThroughputRounds& t) {
    const Setting& on = t.row(kOneThreadOn);
    const Setting& off = t.row(kOneThreadOff);
    auto by_engine = [&](const Setting& s, bool cpu) {
        return t.median_of(s, [&](const OnceResult& r, size_t) {
            return (cpu ? r.cpu : r.wall) / r.engine;
        });
    };
    auto speedup = [&](SettingRow row) {
        return t.median_of(t.row(row),
                           [&](const OnceResult& r, size_t i) { return on.runs[i].wall / r.wall; });
    };
    auto serial_share = [&](SettingRow row) {
        return 100 * t.median_of(t.row(row), [](const OnceResult& r, size_t) {
            return r.replay_thread_cpu / r.wall;
        });
    };
    unsigned long long peak_kb = 0;
    for (const Setting& s : t.settings)
        for (const OnceResult& r : s.runs) peak_kb = std::max(peak_kb, r.peak_kb);
    const OnceResult& ahead = t.row(kRunAhead).runs.back();
    std::printf(
        "replay (1 thread, hazards off) / its engine time: %.3fx (goal <= 1.1x); hazards on / "
        "off, each over its engine time: %.3f / %.3f = %.3fx wall, CPU %.3f / %.3f = %.3fx (goal "
        "<= 1.2x); %u threads vs 1 (its round's 1-thread hazards-on wall over its wall): %.2fx in "
        "turn, %.2fx with the sync model on its own thread, %.2fx with runs ahead, %.2fx with "
        "both (goal >= 8x on 16 cores at 10^6 ops); the replay thread's CPU over the wall (its "
        "serial share) at %u threads: %.0f%% / %.0f%% / %.0f%% / %.0f%%; cluster builds run ahead "
        "%llu, stood %llu, run again %llu (last run); accesses checked: %llu; peak RSS of the "
        "replay processes %.1f MB\n\n",
        by_engine(off, false), by_engine(on, false), by_engine(off, false),
        by_engine(on, false) / by_engine(off, false), by_engine(on, true), by_engine(off, true),
        by_engine(on, true) / by_engine(off, true), t.threads, speedup(kInTurn),
        speedup(kSyncThread), speedup(kRunAhead), speedup(kBoth), t.threads, serial_share(kInTurn),
        serial_share(kSyncThread), serial_share(kRunAhead), serial_share(kBoth), ahead.started,
        ahead.stood, ahead.run_again, on.runs.back().accesses, double(peak_kb) / 1024.0);
}

// Table 1: one trace of `ops` ops, replayed every way (see the file comment).
void throughput_table(const std::string& dir, uint64_t ops, uint32_t threads, int repeats) {
    const std::string path = trace_path(dir, ops);
    bench::BenchTraceShape shape;
    shape.target_ops = ops;
    ThroughputRounds t;
    t.stats = bench::write_bench_trace(path, shape);
    t.threads = threads;
    t.settings = throughput_settings(threads);
    run_rounds(path, repeats, t);
    warn_if_reports_differ(t);
    t.engine_seconds = median_engine_seconds(t);
    t.raw_mb = mb(t.row(kOneThreadOn).runs.back().raw_bytes);
    print_throughput_heading(t, repeats);
    for (const Setting& s : t.settings) print_setting_row(t, s);
    print_peer_rows(t);
    print_throughput_summary(t);
    std::remove(path.c_str());
}

// Table 2: growth with trace length, one child process per size.
void growth_table(const std::string& dir, uint64_t max_ops, uint32_t threads) {
    // Table 1 gives the caller's CLASTRACE_REPLAY_RUN_AHEAD back, so these rows run the library's
    // default unless the variable, set, decides (replayer.cpp runs_ahead).
    const char* asked = std::getenv("CLASTRACE_REPLAY_RUN_AHEAD");
    std::printf(
        "replay time and peak memory by trace length (hazards on, %u threads; each size in a "
        "fresh process; cluster builds run ahead: %s)\n",
        threads,
        asked ? (std::string(asked) == "1"   ? "on (CLASTRACE_REPLAY_RUN_AHEAD=1)"
                 : std::string(asked) == "0" ? "off (CLASTRACE_REPLAY_RUN_AHEAD=0)"
                                             : "the library's default (variable not 0 or 1)")
              : "the library's default (CLASTRACE_REPLAY_RUN_AHEAD unset)");
    std::printf(
        "| ops | submissions | buffers destroyed | trace MB | replay s | ops/s | peak RSS MB | "
        "RSS over start MB | image peak MB | largest submission MB | largest chunk MB (raw) | "
        "distinct contents |\n");
    std::printf("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (uint64_t ops = 100; ops <= max_ops; ops *= 10) {
        const std::string path = trace_path(dir, ops);
        bench::BenchTraceShape shape;
        shape.target_ops = ops;
        const bench::BenchTraceStats stats = bench::write_bench_trace(path, shape);
        ChildResult c = run_child(path, threads);
        const uint64_t chunk = largest_raw_chunk(path);
        std::remove(path.c_str());
        if (!c.ok) {
            std::printf("| %llu | child replay failed |\n", (unsigned long long)ops);
            continue;
        }
        std::printf(
            "| %llu | %llu | %llu | %.2f | %.3f | %.0f | %.1f | %.1f | %.2f | %.3f | %.2f | %llu "
            "|\n",
            (unsigned long long)stats.ops, (unsigned long long)stats.submissions,
            (unsigned long long)stats.buffers_destroyed, mb(stats.file_bytes), c.seconds,
            double(stats.ops) / c.seconds, double(c.peak_kb) / 1024.0,
            double(c.peak_kb - std::min(c.peak_kb, c.base_kb)) / 1024.0, mb(c.image_peak),
            mb(stats.largest_submission_bytes), mb(chunk), (unsigned long long)stats.contents);
        std::fflush(stdout);
    }
}

}  // namespace

int main(int argc, char** argv) {
    uint64_t table_ops = 100000, max_ops = 1000000;
    std::string dir = "/tmp";
    uint32_t threads = replay::replay_threads({});  // the machine's cores
    int repeats = 7;  // the ratio rows are medians: >= 7 rounds (docs/benchmarks.md)
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--child-replay" && i + 2 < argc)
            return child_replay(argv[i + 1], uint32_t(std::strtoul(argv[i + 2], nullptr, 10)));
        if (a == "--replay-once" && i + 2 < argc)
            return replay_once_for_profiler(
                argv[i + 1], std::string(argv[i + 2]) == "hazards",
                i + 3 < argc
                    ? std::max<uint32_t>(1, uint32_t(std::strtoul(argv[i + 3], nullptr, 10)))
                    : 1);
        if (a == "--write-trace" &&
            i + 2 < argc) {  // keep one generated trace, e.g. for a profiler
            bench::BenchTraceShape shape;
            shape.target_ops = std::strtoull(argv[i + 2], nullptr, 10);
            const bench::BenchTraceStats stats = bench::write_bench_trace(argv[i + 1], shape);
            std::printf("%s: %llu ops, %llu submissions\n", argv[i + 1],
                        (unsigned long long)stats.ops, (unsigned long long)stats.submissions);
            return 0;
        }
        if (a == "--ops" && i + 1 < argc)
            table_ops = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--max-ops" && i + 1 < argc)
            max_ops = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--dir" && i + 1 < argc)
            dir = argv[++i];
        else if (a == "--threads" && i + 1 < argc)
            threads = std::max<uint32_t>(1, uint32_t(std::strtoul(argv[++i], nullptr, 10)));
        else if (a == "--repeat" && i + 1 < argc)
            repeats = std::max(1, std::atoi(argv[++i]));
        else {
            std::fprintf(stderr,
                         "usage: %s [--ops N] [--max-ops M] [--dir D] [--threads T] [--repeat R]\n"
                         "       %s --write-trace PATH OPS | --replay-once PATH hazards|no-hazards "
                         "[THREADS]\n",
                         argv[0], argv[0]);
            return 2;
        }
    }
    std::error_code made;
    std::filesystem::create_directories(dir, made);  // --dir may name a folder not made yet
    if (made) {
        std::fprintf(stderr, "cannot create %s: %s\n", dir.c_str(), made.message().c_str());
        return 2;
    }
    if (table_ops > 0) throughput_table(dir, table_ops, threads, repeats);
    if (max_ops > 0) growth_table(dir, max_ops, threads);
    return 0;
}
