// SPDX-License-Identifier: Apache-2.0
// Hostile traces against the reader's bounds: for each crafted file, the CPU seconds and
// peak memory of the reader's full pass with content keys verified (what `clastrace info`
// does), of replay_trace and of analyze_trace. Each pass runs in a forked child, whose
// max RSS wait4 reports. Usage: hostile_input_bench [DIR] (default /tmp). The table is in
// docs/benchmarks.md; the bound it checks: a few seconds per MB, 256 MiB + O(file size).
#include <clastrace/analyze/replay_stream.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include "file_format.h"

#include <zstd.h>

#include <cstdio>
#include <cstring>
#include <functional>
#include <string>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

namespace {

namespace f = clastrace::traces::format;
namespace fbs = clastrace::fbs;
using clastrace::traces::TraceReader;

std::vector<uint8_t> compress(const std::vector<uint8_t>& raw) {
    std::vector<uint8_t> out(ZSTD_compressBound(raw.size()));
    out.resize(ZSTD_compress(out.data(), out.size(), raw.data(), raw.size(), 1));
    return out;
}

// A file header (no TraceHeader: the reader reports that and reads on), chunks, index, trailer.
class HostileFile {
public:
    HostileFile() : file_(f::kFileHeaderSize, 0) {
        f::FileHeader h{};
        std::memcpy(h.magic, f::kFileMagic, 8);
        h.version_major = f::kVersionMajor;
        h.version_minor = f::kVersionMinor;
        h.checksum = f::file_header_checksum(h, nullptr, 0);
        std::memcpy(file_.data(), &h, sizeof h);
    }

    // A records chunk of `raw_size` raw bytes whose payload is `compressed`.
    void add_chunk(const std::vector<uint8_t>& compressed, uint32_t raw_size, uint32_t records,
                   uint32_t submissions, uint16_t kind = 1) {
        index_.chunks.emplace_back(file_.size(), submissions_, submissions, records, raw_size,
                                   static_cast<uint32_t>(compressed.size()));
        index_.record_count += records;
        append(compressed, raw_size, kind, records, submissions_,
               static_cast<uint32_t>(index_.chunks.size() - 1));
        submissions_ += submissions;
        index_.submission_count = submissions_;
    }

    // Index chunk (its payload given, or the real index) and trailer.
    std::vector<uint8_t> finish(const std::vector<uint8_t>* index_payload = nullptr,
                                uint32_t index_raw = 0) {
        const uint64_t at = file_.size();
        if (index_payload) {
            append(*index_payload, index_raw, 2, 0, submissions_,
                   static_cast<uint32_t>(index_.chunks.size()));
        } else {
            flatbuffers::FlatBufferBuilder b;
            b.Finish(fbs::TraceIndex::Pack(b, &index_));
            std::vector<uint8_t> raw(b.GetBufferPointer(), b.GetBufferPointer() + b.GetSize());
            append(compress(raw), static_cast<uint32_t>(raw.size()), 2, 0, submissions_,
                   static_cast<uint32_t>(index_.chunks.size()));
        }
        const f::Trailer t = f::sealed_trailer(at, file_.size());
        const size_t end = file_.size();
        file_.resize(end + sizeof t);
        std::memcpy(file_.data() + end, &t, sizeof t);
        return file_;
    }

private:
    void append(const std::vector<uint8_t>& compressed, uint32_t raw_size, uint16_t kind,
                uint32_t records, uint64_t first_submission, uint32_t number) {
        const f::ChunkHeader h =
            f::sealed_chunk_header(static_cast<f::ChunkKind>(kind), number, records,
                                   first_submission, raw_size, compressed.data(),
                                   static_cast<uint32_t>(compressed.size()));
        const size_t at = file_.size();
        file_.resize(at + sizeof h);
        std::memcpy(file_.data() + at, &h, sizeof h);
        file_.insert(file_.end(), compressed.begin(), compressed.end());
    }

    std::vector<uint8_t> file_;
    fbs::TraceIndexT index_;
    uint64_t submissions_ = 0;
};

// Framed QueueSubmit records, one per submission.
std::vector<uint8_t> submits(uint64_t first, uint32_t count) {
    std::vector<uint8_t> raw;
    for (uint64_t s = first; s < first + count; ++s) {
        fbs::QueueSubmitT q;
        q.submission_index = s;
        fbs::RecordT r;
        r.body.Set(std::move(q));
        flatbuffers::FlatBufferBuilder b;
        b.Finish(fbs::Record::Pack(b, &r));
        uint32_t head[2] = {b.GetSize(), static_cast<uint32_t>(fbs::RecordBody::QueueSubmit)};
        const size_t at = raw.size();
        raw.resize(at + 8 + f::align8(b.GetSize()), 0);
        std::memcpy(raw.data() + at, head, 8);
        std::memcpy(raw.data() + at + 8, b.GetBufferPointer(), b.GetSize());
    }
    return raw;
}

void write(const std::string& path, const std::vector<uint8_t>& bytes) {
    FILE* out = std::fopen(path.c_str(), "wb");
    if (!out || std::fwrite(bytes.data(), 1, bytes.size(), out) != bytes.size() ||
        std::fclose(out) != 0) {
        std::fprintf(stderr, "cannot write %s\n", path.c_str());
        std::exit(2);
    }
}

std::vector<uint8_t> zero_bombs(int chunks) {
    const uint32_t raw = f::kMaxChunkRawBytes;
    const std::vector<uint8_t> payload = compress(std::vector<uint8_t>(raw, 0));
    HostileFile file;
    for (int i = 0; i < chunks; ++i) file.add_chunk(payload, raw, 1, 0);
    return file.finish();
}

std::vector<uint8_t> small_chunks(HostileFile& file, int chunks) {
    for (int i = 0; i < chunks; ++i) {
        std::vector<uint8_t> raw = submits(uint64_t(i) * 4, 4);
        file.add_chunk(compress(raw), static_cast<uint32_t>(raw.size()), 4, 4);
    }
    return {};
}

struct Case {
    const char* name;
    std::function<std::vector<uint8_t>()> make;
};

struct Cost {
    double cpu_s = 0;
    double peak_mib = 0;
    int status = -1;
};

// Runs `pass` in a child; its CPU time and max RSS from wait4.
Cost measure(const std::function<void()>& pass) {
    pid_t pid = fork();
    if (pid == 0) {
        pass();
        _exit(0);
    }
    int status = 0;
    rusage use{};
    wait4(pid, &status, 0, &use);
    Cost c;
    c.cpu_s = double(use.ru_utime.tv_sec + use.ru_stime.tv_sec) +
              1e-6 * double(use.ru_utime.tv_usec + use.ru_stime.tv_usec);
    c.peak_mib = double(use.ru_maxrss) / 1024.0;
    c.status = status;
    return c;
}

std::unique_ptr<TraceReader> open(const std::string& path) {
    clastrace::traces::TraceError e;
    auto reader =
        TraceReader::open(path, &e,
                          clastrace::traces::TraceReaderOptions{.verify_content_keys = true});
    if (!reader) {
        std::fprintf(stderr, "%s\n", e.message.c_str());
        _exit(2);
    }
    return reader;
}

}  // namespace

int main(int argc, char** argv) {
    const std::string dir = argc > 1 ? argv[1] : "/tmp";
    const std::vector<Case> cases = {
        {"64 chunks x 256 MiB zeros", [] { return zero_bombs(64); }},
        {"4 chunks x 256 MiB zeros", [] { return zero_bombs(4); }},
        {"index chunk of 1 GiB raw",
         [] {
             HostileFile file;
             small_chunks(file, 3);
             const std::vector<uint8_t> payload =
                 compress(std::vector<uint8_t>(f::kMaxIndexRawBytes, 0));
             return file.finish(&payload, f::kMaxIndexRawBytes);
         }},
        {"broken frames (256 MiB chunk)",
         [] {
             HostileFile file;
             std::vector<uint8_t> raw(f::kMaxChunkRawBytes, 0xff);  // frames claiming 4 GiB records
             std::vector<uint8_t> zeros(f::kMaxChunkRawBytes, 0);   // frames of size 0
             file.add_chunk(compress(raw), f::kMaxChunkRawBytes, 1, 0);
             file.add_chunk(compress(zeros), f::kMaxChunkRawBytes, 1, 0);
             return file.finish();
         }},
        {"relabelled records chunk",
         [] {
             HostileFile file;
             for (int i = 0; i < 3; ++i) {
                 std::vector<uint8_t> raw = submits(uint64_t(i) * 4, 4);
                 file.add_chunk(compress(raw), static_cast<uint32_t>(raw.size()), 4, 4,
                                i == 1 ? 3 : 1);
             }
             return file.finish();
         }},
    };
    std::printf("| file | size | pass | CPU s | s/MB | peak MiB | damage |\n");
    std::printf("|------|-----:|------|------:|-----:|---------:|-------:|\n");
    for (const Case& c : cases) {
        const std::string path = dir + "/hostile_bench.clt";
        uint64_t size = 0;
        {
            std::vector<uint8_t> bytes = c.make();
            size = bytes.size();
            write(path, bytes);
        }
        const double mb = double(size) / 1e6;
        uint64_t damage = 0;
        const std::vector<std::pair<const char*, std::function<void()>>> passes = {
            {"reader (info)",
             [&] {
                 auto reader = open(path);
                 clastrace::traces::RecordView v;
                 while (reader->next(&v)) {}
                 _exit(reader->damage_count() > 255 ? 255 : int(reader->damage_count()));
             }},
            {"replay_trace",
             [&] {
                 auto reader = open(path);
                 clastrace::replay::replay_trace(*reader, path, {});
             }},
            {"analyze_trace",
             [&] {
                 auto reader = open(path);
                 try {
                     clastrace::analyze::analyze_trace(*reader, path, {});
                 } catch (const std::exception& e) {
                     std::fprintf(stderr, "analyze_trace: %s\n", e.what());
                     _exit(3);
                 }
             }},
        };
        for (const auto& [name, pass] : passes) {
            Cost cost = measure(pass);
            if (std::string(name) == "reader (info)")
                damage = WIFEXITED(cost.status) ? WEXITSTATUS(cost.status) : 0;
            std::printf("| %s | %.3f MB | %s | %.2f | %.2f | %.0f | %s |\n", c.name, mb, name,
                        cost.cpu_s, cost.cpu_s / mb, cost.peak_mib,
                        std::string(name) == "reader (info)" ? std::to_string(damage).c_str() : "");
            std::fflush(stdout);
        }
        std::remove(path.c_str());
    }
    return 0;
}
