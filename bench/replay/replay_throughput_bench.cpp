// SPDX-License-Identifier: Apache-2.0
// replay_throughput_bench [--ops N] [--max-ops M] [--dir D] [--threads T] | --write-trace PATH OPS
// | --child-replay PATH: replay throughput with and
// without hazard checking next to plain zstd decompression of the same trace, then how
// replay time and peak memory grow with trace length.
//
// Table 1 replays one generated trace of N ops (default 10^5) three ways: with hazard
// checking, without (--no-hazards), and the peer: read the file and ZSTD_decompress each
// chunk, nothing else. MB/s are of the trace's decompressed bytes, so the ratio
// replay/zstd says how many times longer the replay takes than merely unpacking the trace.
// Goal: hazards on <= 1.2x hazards off.
//
// Table 2 replays traces of 10^2 .. M ops (default 10^6), each in a fresh child process, so
// its peak RSS is that size's alone; beside it the largest submission's bytes (its records
// plus the memory snapshots it carries). Goal: peak memory bounded by the largest
// submission, not the trace length.
#include "replay_bench_trace.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include <memory>
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

ReplayRun replay_once(const std::string& path, bool hazards) {
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

ZstdRun zstd_once(const std::string& path) {
    ZstdRun run;
    const double t0 = now(), c0 = cpu_now();
    FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) std::exit(1);
    uint8_t file_header[32];
    if (std::fread(file_header, 1, 32, f) != 32) std::exit(1);
    uint32_t header_size = 0;
    std::memcpy(&header_size, file_header + 12, 4);
    std::fseek(f, long(32 + ((header_size + 7) / 8) * 8), SEEK_SET);
    ZSTD_DCtx* dctx = ZSTD_createDCtx();
    std::vector<uint8_t> payload, raw;
    uint8_t h[48];
    while (std::fread(h, 1, 48, f) == 48) {
        if (std::memcmp(h, "CLCK", 4) != 0) break;
        uint16_t kind = 0;
        uint32_t raw_size = 0, compressed_size = 0;
        std::memcpy(&kind, h + 4, 2);
        std::memcpy(&raw_size, h + 16, 4);
        std::memcpy(&compressed_size, h + 20, 4);
        payload.resize(compressed_size);
        if (std::fread(payload.data(), 1, compressed_size, f) != compressed_size) break;
        if (kind != 1) continue;  // the index chunk: the replay does not decompress it either
        raw.resize(raw_size);
        const size_t n =
            ZSTD_decompressDCtx(dctx, raw.data(), raw.size(), payload.data(), payload.size());
        if (ZSTD_isError(n) || n != raw_size) {
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
int child_replay(const std::string& path) {
    const uint64_t base = current_rss_kb();
    ReplayRun run = replay_once(path, true);
    require_clean(run.report, "child");
    std::printf("RESULT %.6f %llu %llu %llu %llu\n", run.seconds, (unsigned long long)peak_rss_kb(),
                (unsigned long long)base, (unsigned long long)run.report.counts.peak_image_bytes,
                (unsigned long long)run.report.counts.commands);
    return 0;
}

struct ChildResult {
    double seconds = 0;
    uint64_t peak_kb = 0, base_kb = 0, image_peak = 0, commands = 0;
    bool ok = false;
};

ChildResult run_child(const char* self, const std::string& path) {
    ChildResult r;
    int fds[2];
    if (pipe(fds) != 0) return r;
    pid_t pid = fork();
    if (pid == 0) {
        dup2(fds[1], 1);
        close(fds[0]);
        close(fds[1]);
        execl(self, self, "--child-replay", path.c_str(), static_cast<char*>(nullptr));
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

}  // namespace

int main(int argc, char** argv) {
    uint64_t table_ops = 100000, max_ops = 1000000;
    std::string dir = "/tmp";
    // --threads N caps the engine's TBB workers: 1 makes CPU time pure work (idle workers
    // spinning would otherwise count), the steadiest ratio on a busy machine.
    std::unique_ptr<tbb::global_control> threads;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--child-replay" && i + 1 < argc) return child_replay(argv[i + 1]);
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
            threads =
                std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                      std::strtoull(argv[++i], nullptr, 10));
        else {
            std::fprintf(stderr, "usage: %s [--ops N] [--max-ops M] [--dir D] [--threads T]\n",
                         argv[0]);
            return 2;
        }
    }

    // ---- Table 1: throughput.
    if (table_ops > 0) {
        const std::string path = trace_path(dir, table_ops);
        bench::BenchTraceShape shape;
        shape.target_ops = table_ops;
        const bench::BenchTraceStats stats = bench::write_bench_trace(path, shape);
        constexpr int kRepeats = 5;
        double on = 1e30, off = 1e30, z = 1e30, on_cpu = 1e30, off_cpu = 1e30, z_cpu = 1e30;
        ReplayRun last_on, last_off;
        ZstdRun zr;
        for (int rep = 0; rep < kRepeats; ++rep) {
            ZstdRun zs = zstd_once(path);
            z = std::min(z, zs.seconds);
            z_cpu = std::min(z_cpu, zs.cpu);
            zr = zs;
            ReplayRun a = replay_once(path, true);
            on = std::min(on, a.seconds);
            on_cpu = std::min(on_cpu, a.cpu);
            ReplayRun b = replay_once(path, false);
            off = std::min(off, b.seconds);
            off_cpu = std::min(off_cpu, b.cpu);
            last_on = std::move(a);
            last_off = std::move(b);
        }
        require_clean(last_on.report, "hazards-on");
        require_clean(last_off.report, "hazards-off");
        const double raw = mb(last_on.raw_bytes);
        const double laid = mb(last_on.report.counts.snapshot_bytes);
        std::printf(
            "replay throughput, %llu ops (%llu cluster ops, %llu commands, %llu submissions), "
            "trace %.2f MB on disk, %.2f MB decompressed, %.2f MB of memory laid in; best of %d, "
            "engine threads: %s\n",
            (unsigned long long)stats.ops, (unsigned long long)stats.cluster_ops,
            (unsigned long long)last_on.report.counts.commands,
            (unsigned long long)stats.submissions, mb(stats.file_bytes), raw, laid, kRepeats,
            threads ? std::to_string(tbb::global_control::active_value(
                                         tbb::global_control::max_allowed_parallelism))
                          .c_str()
                    : "TBB default");
        std::printf(
            "| run | wall s | CPU s (all threads) | ops/s (wall) | trace MB/s (decompressed, wall) "
            "| memory MB/s (laid in, wall) | wall vs zstd | CPU vs zstd |\n");
        std::printf("|---|---:|---:|---:|---:|---:|---:|---:|\n");
        auto row = [&](const char* name, double wall, double cpu) {
            std::printf("| %s | %.3f | %.3f | %.0f | %.1f | %.1f | %.0fx | %.0fx |\n", name, wall,
                        cpu, double(stats.ops) / wall, raw / wall, laid / wall, wall / z,
                        cpu / std::max(z_cpu, 1e-6));
        };
        row("replay, hazards on", on, on_cpu);
        row("replay, hazards off (--no-hazards)", off, off_cpu);
        std::printf(
            "| zstd: read + ZSTD_decompress each chunk (%llu chunks) | %.4f | %.4f | %.0f | %.1f | "
            "- | 1x | 1x |\n",
            (unsigned long long)zr.chunks, z, z_cpu, double(stats.ops) / z, mb(zr.raw_bytes) / z);
        std::printf(
            "hazards on / hazards off: %.2fx wall, %.2fx CPU (goal <= 1.2x); accesses checked: "
            "%llu\n\n",
            on / off, on_cpu / off_cpu, (unsigned long long)last_on.report.counts.accesses);
        std::remove(path.c_str());
    }

    // ---- Table 2: growth with trace length, one child process per size.
    if (max_ops > 0) {
        std::printf(
            "replay time and peak memory by trace length (hazards on; each size in a fresh "
            "process)\n");
        std::printf(
            "| ops | submissions | buffers destroyed | trace MB | replay s | ops/s | peak RSS MB | "
            "RSS over start MB "
            "| image peak MB | largest submission MB | distinct contents |\n");
        std::printf("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
        for (uint64_t ops = 100; ops <= max_ops; ops *= 10) {
            const std::string path = trace_path(dir, ops);
            bench::BenchTraceShape shape;
            shape.target_ops = ops;
            const bench::BenchTraceStats stats = bench::write_bench_trace(path, shape);
            ChildResult c = run_child("/proc/self/exe", path);
            std::remove(path.c_str());
            if (!c.ok) {
                std::printf("| %llu | child replay failed |\n", (unsigned long long)ops);
                continue;
            }
            std::printf(
                "| %llu | %llu | %llu | %.2f | %.3f | %.0f | %.1f | %.1f | %.2f | %.3f | %llu |\n",
                (unsigned long long)stats.ops, (unsigned long long)stats.submissions,
                (unsigned long long)stats.buffers_destroyed, mb(stats.file_bytes), c.seconds,
                double(stats.ops) / c.seconds, double(c.peak_kb) / 1024.0,
                double(c.peak_kb - std::min(c.peak_kb, c.base_kb)) / 1024.0, mb(c.image_peak),
                mb(stats.largest_submission_bytes), (unsigned long long)stats.contents);
            std::fflush(stdout);
        }
    }
    return 0;
}
