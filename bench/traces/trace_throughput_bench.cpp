// SPDX-License-Identifier: Apache-2.0
// trace_throughput_bench [MB] [DIR] [whole] [reads=N | writes=N [keep]] [level=L] [threads=N]
//                        [repeat=N]:
// trace write and read throughput next to plain zstd at the same level on the same bytes.
// Goals (issue 23): write >= 1.0x, read >= 0.8x.
// repeat=N: zstd's decompression and the two reads run N times, interleaved, and the read
// columns are medians (the ratios: medians of each run's ratio against its own zstd run).
//
// The bytes are what a cluster capture stores: vertex positions (float3 grids with
// smooth noise), 8-bit cluster-local indices, VkClusterAccelerationStructureBuild-
// TriangleClusterInfoNV arrays, and every fourth frame repeating the previous
// geometry (deduplicated by the trace, so it is not counted as stored bytes).
// "Raw MB" is the bytes stored once; zstd compresses exactly those, in chunks of the
// trace's chunk size, single-threaded. The trace is written to DIR (default /dev/shm)
// so the disk does not dominate.
#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_writer.h>
#include <clastrace/vk_cluster_abi.h>

#include <zstd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <random>
#include <string>
#include <sys/resource.h>
#include <unistd.h>
#include <vector>

using namespace clastrace;
using namespace clastrace::traces;

namespace {

// Wall time and process CPU time (all threads) together: on a shared, oversubscribed
// machine wall time mostly measures the neighbours, CPU time measures our work. Page faults
// too: a fresh page's first touch costs about what a copy of it does, and instruction counts
// do not show it.
struct Stamp {
    std::chrono::steady_clock::time_point wall;
    double cpu;
    long faults;
};
double cpu_now() {
    timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
}
long faults_now() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return u.ru_minflt + u.ru_majflt;
}
struct Clock {
    static Stamp now() { return {std::chrono::steady_clock::now(), cpu_now(), faults_now()}; }
};
struct Elapsed {
    double wall, cpu;
    long faults;
};
Elapsed seconds_since(Stamp t) {
    return {std::chrono::duration<double>(std::chrono::steady_clock::now() - t.wall).count(),
            cpu_now() - t.cpu, faults_now() - t.faults};
}

struct Frame {
    std::vector<uint8_t> vertices, indices, infos;
};

// One frame's build inputs: `clusters` clusters of 9x9-vertex grids, 128 triangles each.
Frame make_frame(int frame, int clusters, std::mt19937& rng) {
    Frame f;
    std::vector<float> v;
    v.reserve(clusters * 81 * 3);
    std::normal_distribution<float> noise(0.0f, 0.002f);
    for (int c = 0; c < clusters; ++c) {
        float ox = static_cast<float>(c % 64), oy = static_cast<float>(c / 64);
        for (int y = 0; y < 9; ++y)
            for (int x = 0; x < 9; ++x) {
                float fx = ox + x / 8.0f, fy = oy + y / 8.0f;
                v.push_back(fx);
                v.push_back(fy);
                v.push_back(0.25f * std::sin(fx * 0.7f + frame * 0.05f) * std::cos(fy * 0.3f) +
                            noise(rng));
            }
    }
    f.vertices.resize(v.size() * 4);
    std::memcpy(f.vertices.data(), v.data(), f.vertices.size());
    for (int c = 0; c < clusters; ++c) {
        for (int y = 0; y < 8; ++y)
            for (int x = 0; x < 8; ++x) {
                uint8_t a = static_cast<uint8_t>(y * 9 + x), b = a + 1, cc = a + 9, d = cc + 1;
                if (rng() & 1) {
                    f.indices.insert(f.indices.end(), {a, b, cc, b, d, cc});
                } else {
                    f.indices.insert(f.indices.end(), {a, b, d, a, d, cc});
                }
            }
    }
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> infos(clusters);
    for (int c = 0; c < clusters; ++c) {
        auto& i = infos[c];
        std::memset(&i, 0, sizeof i);
        i.clusterID = static_cast<uint32_t>(c);
        i.triangleCount = 128;
        i.vertexCount = 81;
        i.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
        i.indexBufferStride = 1;
        i.vertexBufferStride = 12;
        i.indexBuffer = 0x7f0000000000ull + static_cast<uint64_t>(c) * 384;
        i.vertexBuffer = 0x7f1000000000ull + static_cast<uint64_t>(c) * 972;
    }
    f.infos.resize(infos.size() * sizeof(infos[0]));
    std::memcpy(f.infos.data(), infos.data(), f.infos.size());
    return f;
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    const size_t n = v.size();
    return n % 2 ? v[n / 2] : (v[n / 2 - 1] + v[n / 2]) / 2;
}

// Each field's median over the runs (a column of the table, not one run).
Elapsed median(const std::vector<Elapsed>& runs) {
    std::vector<double> wall, cpu, faults;
    for (const Elapsed& e : runs) {
        wall.push_back(e.wall);
        cpu.push_back(e.cpu);
        faults.push_back(static_cast<double>(e.faults));
    }
    return {median(wall), median(cpu), static_cast<long>(median(faults))};
}

// Median over runs of zstd's time / the reader's, each run against the zstd run before it.
struct Ratios {
    double wall, cpu;
};
Ratios median_ratio(const std::vector<Elapsed>& zstd, const std::vector<Elapsed>& reader) {
    std::vector<double> wall, cpu;
    for (size_t i = 0; i < zstd.size(); ++i) {
        wall.push_back(zstd[i].wall / reader[i].wall);
        cpu.push_back(zstd[i].cpu / reader[i].cpu);
    }
    return {median(wall), median(cpu)};
}

struct Result {
    double raw_mb, trace_ratio, zstd_ratio;
    Elapsed write, zstd_c, read, read_keys, zstd_d;  // read: default options; medians
    Ratios read_vs_zstd, read_keys_vs_zstd;          // medians of the runs' ratios
    uint64_t deltas = 0, deltas_decoded_ahead = 0;   // of the read with default options
    uint64_t chunk_buffer_bytes = 0;                 // the reader's, at the end of that read
};

// One read of the whole trace at `path`, every record handed out and every content touched;
// exits when it does not give back `raw` stored bytes without damage.
Elapsed read_trace(const std::string& path, bool verify_keys, uint64_t raw, TraceReadStats* stats,
                   uint64_t* sink) {
    const Stamp t0 = Clock::now();
    TraceError e;
    TraceReaderOptions ropts;
    ropts.verify_content_keys = verify_keys;
    auto reader = TraceReader::open(path, &e, ropts);
    if (!reader) {
        std::fprintf(stderr, "%s\n", e.message.c_str());
        std::exit(2);
    }
    RecordView v;
    uint64_t read_bytes = 0;
    while (reader->next(&v)) {
        if (const std::optional<traces::ContentsRecord> c = traces::contents_record(*v.record)) {
            read_bytes += c->size();
            *sink += c->bytes->Get(c->size() / 2);
        }
    }
    const Elapsed took = seconds_since(t0);
    *stats = reader->stats();
    if (reader->damage_count() != 0 || read_bytes != raw) {
        std::fprintf(stderr, "read back %llu of %llu bytes, %llu damage\n",
                     (unsigned long long)read_bytes, (unsigned long long)raw,
                     (unsigned long long)reader->damage_count());
        std::exit(1);
    }
    return took;
}

// The writer's compression threads ("threads=N"; default the writer's default, 1).
uint32_t compression_threads = TraceWriterOptions{}.compressor_threads;

// Writes the frames as a trace at `path`: every frame's snapshots go through add_contents and one
// build record. Exits on an error.
TraceWriterStats write_trace(const std::vector<Frame>& frames, const std::vector<int>& repeat_of,
                             int level, uint32_t chunk, const std::string& path, bool deltas) {
    TraceError e;
    TraceWriterOptions options;
    options.zstd_level = level;
    options.chunk_raw_bytes = chunk;
    options.sync_on_finish = false;
    options.delta_contents = deltas;
    options.compressor_threads = compression_threads;
    fbs::TraceHeaderT header;
    auto w = TraceWriter::create(path, header, options, &e);
    if (!w) {
        std::fprintf(stderr, "%s\n", e.message.c_str());
        std::exit(2);
    }
    for (size_t i = 0; i < frames.size(); ++i) {
        const Frame& f = frames[repeat_of[i]];
        fbs::CmdBuildClusterAccelerationStructureIndirectT build;
        build.command_buffer = 1;
        fbs::MemorySnapshot s;
        for (const std::vector<uint8_t>* bytes : {&f.infos, &f.indices, &f.vertices}) {
            if ((e = w->snapshot(1, 0, 0x1000, bytes->data(), bytes->size(), &s))) break;
            build.inputs.push_back(s);
        }
        fbs::RecordT rec;
        rec.body.Set(std::move(build));
        if (!e) e = w->append(rec);
        if (e) break;
    }
    if (!e) e = w->finish();
    if (e) {
        std::fprintf(stderr, "%s\n", e.message.c_str());
        std::exit(2);
    }
    return w->stats();
}

// The bytes the trace stores once (every distinct frame's snapshots, in order): what plain zstd
// compresses.
std::vector<uint8_t> stored_bytes(const std::vector<Frame>& frames,
                                  const std::vector<int>& repeat_of) {
    std::vector<uint8_t> plain;
    std::vector<bool> seen(frames.size());
    for (size_t i = 0; i < frames.size(); ++i) {
        if (seen[repeat_of[i]]) continue;
        seen[repeat_of[i]] = true;
        const Frame& f = frames[repeat_of[i]];
        for (const std::vector<uint8_t>* bytes : {&f.infos, &f.indices, &f.vertices})
            plain.insert(plain.end(), bytes->begin(), bytes->end());
    }
    return plain;
}

// Plain zstd of `plain` in chunks of `chunk` bytes, one thread; the frames go to `blocks` when
// given. Returns the compressed bytes.
uint64_t zstd_chunks(const std::vector<uint8_t>& plain, int level, uint32_t chunk,
                     std::vector<std::vector<uint8_t>>* blocks) {
    ZSTD_CCtx* cctx = ZSTD_createCCtx();
    uint64_t compressed = 0;
    for (size_t at = 0; at < plain.size(); at += chunk) {
        size_t n = std::min<size_t>(chunk, plain.size() - at);
        std::vector<uint8_t> out(ZSTD_compressBound(n));
        out.resize(ZSTD_compressCCtx(cctx, out.data(), out.size(), plain.data() + at, n, level));
        compressed += out.size();
        if (blocks) blocks->push_back(std::move(out));
    }
    ZSTD_freeCCtx(cctx);
    return compressed;
}

Result run(const std::vector<Frame>& frames, const std::vector<int>& repeat_of, int level,
           uint32_t chunk, const std::string& path, bool deltas, int repeat) {
    Result r{};
    auto t0 = Clock::now();
    const TraceWriterStats st = write_trace(frames, repeat_of, level, chunk, path, deltas);
    r.write = seconds_since(t0);
    uint64_t raw = st.contents_bytes_stored;
    r.raw_mb = raw / 1e6;
    r.trace_ratio = static_cast<double>(raw) / static_cast<double>(st.compressed_bytes);

    // Plain zstd on the same stored bytes, chunked the same way.
    const std::vector<uint8_t> plain = stored_bytes(frames, repeat_of);
    std::vector<std::vector<uint8_t>> blocks;
    t0 = Clock::now();
    const uint64_t compressed = zstd_chunks(plain, level, chunk, &blocks);
    r.zstd_c = seconds_since(t0);
    r.zstd_ratio = static_cast<double>(plain.size()) / static_cast<double>(compressed);

    ZSTD_DCtx* dctx = ZSTD_createDCtx();
    std::vector<uint8_t> out(chunk);
    uint64_t sink = 0;
    std::vector<Elapsed> zstd_d, read, read_keys;
    for (int run = 0; run < repeat; ++run) {
        t0 = Clock::now();
        for (const auto& b : blocks) {
            size_t n = ZSTD_decompressDCtx(dctx, out.data(), out.size(), b.data(), b.size());
            sink += out[n / 2];
        }
        zstd_d.push_back(seconds_since(t0));
        // Trace read: every record verified; content keys trusted (default) or recomputed.
        for (bool verify : {false, true}) {
            TraceReadStats rs;
            (verify ? read_keys : read).push_back(read_trace(path, verify, raw, &rs, &sink));
            if (!verify) {
                r.deltas = st.contents_delta_stored;
                r.deltas_decoded_ahead = rs.deltas_decoded_ahead;
                r.chunk_buffer_bytes = rs.chunk_buffer_bytes;
            }
        }
    }
    ZSTD_freeDCtx(dctx);
    r.zstd_d = median(zstd_d);
    r.read = median(read);
    r.read_keys = median(read_keys);
    r.read_vs_zstd = median_ratio(zstd_d, read);
    r.read_keys_vs_zstd = median_ratio(zstd_d, read_keys);
    if (sink == 42) std::printf(" ");
    ::unlink(path.c_str());
    return r;
}

// "reads=N": the trace written once at level 3, then read N times with the default options and
// nothing else timed, for profilers (callgrind, perf) to see the reader alone.
void profile_reads(const std::vector<Frame>& frames, const std::vector<int>& repeat_of,
                   const std::string& path, bool deltas, int reads) {
    const TraceWriterStats st = write_trace(frames, repeat_of, 3, 4u << 20, path, deltas);
    const uint64_t raw = st.contents_bytes_stored;
    uint64_t sink = 0;
    for (int i = 0; i < reads; ++i) {
        TraceReadStats rs;
        const Elapsed took = read_trace(path, false, raw, &rs, &sink);
        std::printf(
            "read %d: %.1f MB in %.3f s wall, %.3f s cpu (%.1f MB/s wall), %ld page faults; "
            "deltas decoded ahead %llu of %llu; fresh buffers for real bytes %.1f MB; "
            "chunks' raw bytes %.1f MB, decompressed %.1f MB\n",
            i, raw / 1e6, took.wall, took.cpu, raw / 1e6 / took.wall, took.faults,
            (unsigned long long)rs.deltas_decoded_ahead,
            (unsigned long long)st.contents_delta_stored, rs.real_bytes_allocated / 1e6,
            rs.raw_bytes / 1e6, rs.raw_bytes_decompressed / 1e6);
    }
    if (sink == 42) std::printf(" ");
    ::unlink(path.c_str());
}

// "writes=N": the trace written N times at `level` and nothing else timed, then plain zstd on
// the same stored bytes N times, for profilers (callgrind, perf) to compare the writer with zstd.
void profile_writes(const std::vector<Frame>& frames, const std::vector<int>& repeat_of,
                    const std::string& path, bool deltas, int writes, int level, bool keep) {
    const std::vector<uint8_t> plain = stored_bytes(frames, repeat_of);
    for (int i = 0; i < writes; ++i) {
        const Stamp t0 = Clock::now();
        const TraceWriterStats st = write_trace(frames, repeat_of, level, 4u << 20, path, deltas);
        const Elapsed took = seconds_since(t0);
        const Stamp t1 = Clock::now();
        const uint64_t compressed = zstd_chunks(plain, level, 4u << 20, nullptr);
        const Elapsed zstd = seconds_since(t1);
        std::printf(
            "write %d at level %d: %.1f MB in %.3f s wall, %.3f s cpu (compression thread %.3f s "
            "cpu, zstd and streams %.3f s wall; %llu bytes); plain zstd %.3f s wall, %.3f s cpu "
            "(%llu bytes)\n",
            i, level, st.contents_bytes_stored / 1e6, took.wall, took.cpu,
            st.compressor_cpu_ns * 1e-9, st.compress_ns * 1e-9,
            (unsigned long long)st.compressed_bytes, zstd.wall, zstd.cpu,
            (unsigned long long)compressed);
    }
    if (!keep) ::unlink(path.c_str());
}

}  // namespace

int main(int argc, char** argv) {
    double target_mb = argc > 1 ? std::atof(argv[1]) : 256;
    std::string dir = argc > 2 ? argv[2] : "/dev/shm";
    // "whole": every content stored whole (the format before delta contents), for comparison.
    // "reads=N": see profile_reads.
    // "writes=N": see profile_writes ("keep": leave its trace in DIR). "level=L": that level
    // alone (default 1, 3 and 9). "threads=N": the writer's compression threads.
    bool deltas = true, keep = false;
    int reads = 0, writes = 0, only_level = 0, repeat = 1;
    for (int i = 3; i < argc; ++i) {
        const std::string arg = argv[i];
        if (arg == "whole") deltas = false;
        if (arg == "keep") keep = true;
        if (arg.rfind("reads=", 0) == 0) reads = std::atoi(arg.c_str() + 6);
        if (arg.rfind("writes=", 0) == 0) writes = std::atoi(arg.c_str() + 7);
        if (arg.rfind("level=", 0) == 0) only_level = std::atoi(arg.c_str() + 6);
        if (arg.rfind("threads=", 0) == 0)
            compression_threads = static_cast<uint32_t>(std::atoi(arg.c_str() + 8));
        if (arg.rfind("repeat=", 0) == 0) repeat = std::max(1, std::atoi(arg.c_str() + 7));
    }
    const int clusters = 4096;  // ~4.4 MB of inputs per frame
    std::mt19937 rng(1);
    std::vector<Frame> frames;
    std::vector<int> repeat_of;
    double stored = 0;
    for (int i = 0; stored < target_mb * 1e6; ++i) {
        if (i % 4 == 3) {
            repeat_of.push_back(static_cast<int>(frames.size()) -
                                1);  // the previous geometry again
            frames.push_back({});
            continue;
        }
        frames.push_back(make_frame(i, clusters, rng));
        repeat_of.push_back(i);
        stored += frames.back().vertices.size() + frames.back().indices.size() +
                  frames.back().infos.size();
    }
    if (reads > 0) {
        profile_reads(frames, repeat_of, dir + "/clastrace-bench.clt", deltas, reads);
        return 0;
    }
    if (writes > 0) {
        profile_writes(frames, repeat_of, dir + "/clastrace-bench.clt", deltas, writes,
                       only_level ? only_level : 3, keep);
        return 0;
    }
    std::printf(
        "trace throughput vs plain zstd (same level, same stored bytes, %u-byte chunks; %zu "
        "frames, every 4th repeated; contents %s; %u compression thread(s); reads: median of %d "
        "interleaved runs)\n",
        4u << 20, frames.size(), deltas ? "as deltas where they can" : "whole", compression_threads,
        repeat);
    std::printf(
        "MB/s of stored bytes; 'wall' = elapsed time, 'cpu' = process CPU time of all threads\n");
    std::printf("%-5s %7s | %-27s | %-27s | %-27s | %-27s | %6s %6s\n", "level", "raw MB",
                "trace write MB/s wall (cpu)", "zstd compress MB/s wall(cpu)",
                "trace read MB/s wall (cpu)", "zstd decomp MB/s wall (cpu)", "trace", "zstd");
    for (int level : {1, 3, 9}) {
        if (only_level && level != only_level) continue;
        Result r =
            run(frames, repeat_of, level, 4u << 20, dir + "/clastrace-bench.clt", deltas, repeat);
        auto mbs = [&](double s) { return r.raw_mb / s; };
        std::printf(
            "%-5d %7.1f | %7.1f (%7.1f)           | %7.1f (%7.1f)           | %7.1f (%7.1f)        "
            "   | %7.1f (%7.1f)           | %5.2fx %5.2fx\n",
            level, r.raw_mb, mbs(r.write.wall), mbs(r.write.cpu), mbs(r.zstd_c.wall),
            mbs(r.zstd_c.cpu), mbs(r.read.wall), mbs(r.read.cpu), mbs(r.zstd_d.wall),
            mbs(r.zstd_d.cpu), r.trace_ratio, r.zstd_ratio);
        std::printf(
            "      ratio vs zstd: write %.2fx wall, %.2fx cpu;  read %.2fx wall, %.2fx cpu"
            "  (with content-key check: %.1f MB/s wall, %.2fx wall, %.2fx cpu)\n",
            r.zstd_c.wall / r.write.wall, r.zstd_c.cpu / r.write.cpu, r.read_vs_zstd.wall,
            r.read_vs_zstd.cpu, mbs(r.read_keys.wall), r.read_keys_vs_zstd.wall,
            r.read_keys_vs_zstd.cpu);
        std::printf(
            "      deltas %llu, decoded on the read-ahead task %llu; reader's chunk buffers "
            "%.1f MB at the end; page faults: read %ld, zstd decompression %ld\n",
            (unsigned long long)r.deltas, (unsigned long long)r.deltas_decoded_ahead,
            r.chunk_buffer_bytes / 1e6, r.read.faults, r.zstd_d.faults);
    }
    return 0;
}
