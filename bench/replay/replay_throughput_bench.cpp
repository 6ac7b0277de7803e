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
// ahead of their turn (CLASTRACE_REPLAY_RUN_AHEAD=1, docs/replay.md "Threads"), and with both; then the engine alone: the wall
// time of every engine::execute call of a one-thread replay of the same trace in the same process (ReplayedCommand::engine_ns, summed
// by an observer), i.e. exactly the ops the replay ran; and the peer: read the file and
// ZSTD_decompress each chunk, nothing else. Goals (issue 23): replay (one thread) <= 1.1x the
// engine alone, hazards on <= 1.2x hazards off, T threads >= 8x one thread on 16 cores at 10^6
// ops. Each row is the best of R runs (--repeat R, default 5).
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
    const double t0 = now(), c0 = cpu_now();
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
    return 0;
}

struct ChildResult {
    double seconds = 0;
    uint64_t peak_kb = 0, base_kb = 0, image_peak = 0, commands = 0;
    bool ok = false;
};

ChildResult run_child(const char* self, const std::string& path, uint32_t threads) {
    ChildResult r;
    int fds[2];
    if (pipe(fds) != 0) return r;
    pid_t pid = fork();
    if (pid == 0) {
        dup2(fds[1], 1);
        close(fds[0]);
        close(fds[1]);
        const std::string count = std::to_string(threads);
        execl(self, self, "--child-replay", path.c_str(), count.c_str(),
              static_cast<char*>(nullptr));
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
    unsigned long long peak = 0, base = 0, image = 0, commands = 0;
    if (at != std::string::npos && std::sscanf(out.c_str() + at, "RESULT %lf %llu %llu %llu %llu",
                                               &r.seconds, &peak, &base, &image, &commands) == 5) {
        r.peak_kb = peak;
        r.base_kb = base;
        r.image_peak = image;
        r.commands = commands;
        r.ok = WIFEXITED(status) && WEXITSTATUS(status) == 0;
    }
    return r;
}

double mb(uint64_t bytes) { return double(bytes) / 1e6; }

// Table 1: one trace of `ops` ops, replayed every way (see the file comment).
void throughput_table(const std::string& dir, uint64_t ops, uint32_t threads, int repeats) {
    const std::string path = trace_path(dir, ops);
    bench::BenchTraceShape shape;
    shape.target_ops = ops;
    const bench::BenchTraceStats stats = bench::write_bench_trace(path, shape);
    struct Best {
        double wall = 1e30, cpu = 1e30;
        void take(double w, double c) {
            wall = std::min(wall, w);
            cpu = std::min(cpu, c);
        }
    } on, off, many, many_sync_thread, many_run_ahead, many_both, engine, z;
    replay::ReplayOptions::RunAheadCounts run_ahead;
    ReplayRun last_on, last_many;
    ZstdRun zr;
    EngineTime engine_last;
    for (int rep = 0; rep < repeats; ++rep) {
        zr = zstd_once(path);
        z.take(zr.seconds, zr.cpu);
        ReplayRun a = replay_once(path, true, 1);
        on.take(a.seconds, a.cpu);
        ReplayRun b = replay_once(path, false, 1);
        off.take(b.seconds, b.cpu);
        setenv("CLASTRACE_REPLAY_RUN_AHEAD", "0", 1);  // model inline, every build in its turn
        ReplayRun m = replay_once(path, true, threads);
        many.take(m.seconds, m.cpu);
        setenv("CLASTRACE_REPLAY_RUN_AHEAD", "1", 1);  // cluster builds run ahead on T threads
        ReplayRun t = replay_once(path, true, threads, nullptr, &run_ahead);
        unsetenv("CLASTRACE_REPLAY_RUN_AHEAD");
        many_run_ahead.take(t.seconds, t.cpu);
        setenv("CLASTRACE_REPLAY_RUN_AHEAD", "0", 1);
        setenv("CLASTRACE_REPLAY_SYNC_THREAD", "1", 1);  // the model on a thread of its own
        ReplayRun mi = replay_once(path, true, threads);
        unsetenv("CLASTRACE_REPLAY_RUN_AHEAD");
        unsetenv("CLASTRACE_REPLAY_SYNC_THREAD");
        many_sync_thread.take(mi.seconds, mi.cpu);
        setenv("CLASTRACE_REPLAY_RUN_AHEAD", "1", 1);  // both
        setenv("CLASTRACE_REPLAY_SYNC_THREAD", "1", 1);
        ReplayRun both = replay_once(path, true, threads);
        unsetenv("CLASTRACE_REPLAY_RUN_AHEAD");
        unsetenv("CLASTRACE_REPLAY_SYNC_THREAD");
        many_both.take(both.seconds, both.cpu);
        EngineTime timed;
        replay_once(path, true, 1, &timed);
        engine.take(double(timed.ns) * 1e-9, double(timed.ns) * 1e-9);  // one thread: CPU = wall
        engine_last = timed;
        last_on = std::move(a);
        last_many = std::move(m);
    }
    require_clean(last_on.report, "one-thread");
    require_clean(last_many.report, "many-thread");
    if (replay::to_json(last_on.report) != replay::to_json(last_many.report))
        std::fprintf(stderr, "warning: the %u-thread report differs from the one-thread one\n",
                     threads);
    const double raw = mb(last_on.raw_bytes);
    std::printf(
        "replay throughput, %llu ops (%llu cluster ops, %llu commands, %llu engine calls, %llu "
        "submissions), trace %.2f MB on disk, %.2f MB decompressed, %.2f MB of memory laid in; "
        "best of %d\n",
        (unsigned long long)stats.ops, (unsigned long long)stats.cluster_ops,
        (unsigned long long)last_on.report.counts.commands,
        (unsigned long long)engine_last.commands, (unsigned long long)stats.submissions,
        mb(stats.file_bytes), raw, mb(last_on.report.counts.snapshot_bytes), repeats);
    std::printf(
        "| run | wall s | CPU s (all threads) | ops/s (wall) | trace MB/s (decompressed, wall) "
        "| wall vs engine alone | wall vs zstd |\n");
    std::printf("|---|---:|---:|---:|---:|---:|---:|\n");
    auto row = [&](const std::string& name, const Best& b) {
        std::printf("| %s | %.4f | %.4f | %.0f | %.1f | %.2fx | %.1fx |\n", name.c_str(), b.wall,
                    b.cpu, double(stats.ops) / b.wall, raw / b.wall, b.wall / engine.wall,
                    b.wall / z.wall);
    };
    row("replay, 1 thread, hazards on", on);
    row("replay, 1 thread, hazards off (--no-hazards)", off);
    row("replay, " + std::to_string(threads) +
            " threads, hazards on, every build in its turn (CLASTRACE_REPLAY_RUN_AHEAD=0)",
        many);
    row("replay, " + std::to_string(threads) +
            " threads, hazards on, sync model on its own thread (CLASTRACE_REPLAY_SYNC_THREAD=1, "
            "RUN_AHEAD=0)",
        many_sync_thread);
    row("replay, " + std::to_string(threads) +
            " threads, hazards on, cluster builds run ahead (CLASTRACE_REPLAY_RUN_AHEAD=1)",
        many_run_ahead);
    row("replay, " + std::to_string(threads) +
            " threads, hazards on, the model's thread and runs ahead (both =1)",
        many_both);
    row("engine alone: engine::execute of the same ops (1 thread, summed)", engine);
    row("zstd: read + ZSTD_decompress each chunk (" + std::to_string(zr.chunks) + " chunks)", z);
    std::printf(
        "replay (1 thread, hazards off) / engine alone: %.2fx (goal <= 1.1x); hazards on / off: "
        "%.2fx wall, %.2fx CPU (goal <= 1.2x); %u threads vs 1: %.2fx (goal >= 8x on 16 cores at "
        "10^6 ops), %.2fx with the sync model on its own thread, %.2fx with runs ahead, %.2fx "
        "with both; cluster "
        "builds "
        "run ahead %llu, stood %llu, run again %llu (last run); accesses checked: %llu; peak RSS "
        "of this process %.1f MB\n\n",
        off.wall / engine.wall, on.wall / off.wall, on.cpu / off.cpu, threads, on.wall / many.wall,
        on.wall / many_sync_thread.wall, on.wall / many_run_ahead.wall, on.wall / many_both.wall,
        (unsigned long long)run_ahead.started, (unsigned long long)run_ahead.stood,
        (unsigned long long)run_ahead.run_again, (unsigned long long)last_on.report.counts.accesses,
        double(peak_rss_kb()) / 1024.0);
    std::remove(path.c_str());
}

// Table 2: growth with trace length, one child process per size.
void growth_table(const std::string& dir, uint64_t max_ops, uint32_t threads) {
    // Table 1 leaves CLASTRACE_REPLAY_RUN_AHEAD unset, so these rows run the library's default;
    // the variable, when set, decides (replayer.cpp runs_ahead).
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
        ChildResult c = run_child("/proc/self/exe", path, threads);
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
    int repeats = 5;
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
