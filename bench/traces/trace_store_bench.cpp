// SPDX-License-Identifier: Apache-2.0
// trace_store_bench TRACE [DIR]: how the trace's contents are stored, measured on a real capture.
// The trace is written again through TraceWriter::snapshot, snapshot by snapshot in its own
// order (as the capture layer wrote it), once per storage setting, and each result is read back
// (every record, and every snapshot's bytes through read_contents). Printed per setting: the
// file's bytes against plain zstd of the referenced bytes at the same level (issue 23's goal:
// <= 1.0x), contents stored whole and as deltas, and the write and read times (CPU).
// DIR (default /dev/shm) holds the rewritten traces, so the disk does not dominate.
#include <clastrace/traces/records.h>
#include <clastrace/traces/referenced_zstd.h>
#include <clastrace/traces/trace_reader.h>
#include <clastrace/traces/trace_writer.h>

#include <cstdio>
#include <ctime>
#include <filesystem>
#include <string>
#include <unistd.h>
#include <unordered_map>
#include <vector>

using namespace clastrace;
using namespace clastrace::traces;

namespace {

double cpu_now() {
    timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
}

[[noreturn]] void fail(const std::string& what) {
    std::fprintf(stderr, "trace_store_bench: %s\n", what.c_str());
    std::exit(2);
}

struct Setting {
    const char* name;
    TraceWriterOptions options;
    bool contents = true;  // false: the records alone, their snapshots not stored (for scale)
};

struct Outcome {
    uint64_t file_bytes = 0;
    TraceWriterStats stats;
    double write_cpu_s = 0, read_cpu_s = 0;
};

// Writes `from` again under `options`: every snapshot through snapshot(), every record as it was.
Outcome rewrite(const std::string& from, const std::string& to, const TraceWriterOptions& options,
                bool contents) {
    Outcome o;
    TraceError e;
    auto reader = TraceReader::open(from, &e);
    if (!reader || !reader->header()) fail(from + ": " + e.message);
    std::unique_ptr<fbs::TraceHeaderT> header(reader->header()->UnPack());
    std::unordered_map<uint64_t, std::vector<uint8_t>> bytes_of;  // the trace's contents
    std::vector<fbs::RecordT> records;
    RecordView view;
    while (reader->next(&view)) {
        if (const std::optional<ContentsRecord> c = contents_record(*view.record)) {
            bytes_of[c->hash].assign(c->data(), c->data() + c->size());
            continue;
        }
        records.emplace_back();
        view.record->UnPackTo(&records.back());
    }
    const double started = cpu_now();
    auto writer = TraceWriter::create(to, *header, options, &e);
    if (!writer) fail(to + ": " + e.message);
    for (const fbs::RecordT& record : records) {
        flatbuffers::FlatBufferBuilder b;
        b.Finish(fbs::Record::Pack(b, &record));
        const SnapshotLists lists =
            !contents ? SnapshotLists{} : record_snapshots(*fbs::GetRecord(b.GetBufferPointer()));
        for (const SnapshotVector* list : {lists.inputs, lists.outputs})
            if (list)
                for (const fbs::MemorySnapshot* s : *list) {
                    const std::vector<uint8_t>& bytes = bytes_of.at(s->hash());
                    fbs::MemorySnapshot again;
                    if ((e = writer->snapshot(s->buffer(), s->offset(), s->address(), bytes.data(),
                                              bytes.size(), &again)))
                        fail(e.message);
                    if (again.hash() != s->hash()) fail("a content got another key");
                }
        if ((e = writer->append_record_bytes(b.GetBufferPointer(), b.GetSize()))) fail(e.message);
    }
    if ((e = writer->finish())) fail(e.message);
    o.write_cpu_s = cpu_now() - started;
    o.stats = writer->stats();
    o.file_bytes = std::filesystem::file_size(to);

    if (!contents) return o;  // records alone: nothing to read back
    const double read_started = cpu_now();
    auto back = TraceReader::open(to, &e);
    if (!back) fail(to + ": " + e.message);
    std::vector<uint8_t> bytes;
    uint64_t checked = 0;
    while (back->next(&view)) {
        const SnapshotLists lists = record_snapshots(*view.record);
        for (const SnapshotVector* list : {lists.inputs, lists.outputs})
            if (list)
                for (const fbs::MemorySnapshot* s : *list) {
                    if ((e = back->read_contents(s->hash(), &bytes))) fail(e.message);
                    checked += bytes == bytes_of.at(s->hash());
                }
    }
    o.read_cpu_s = cpu_now() - read_started;
    if (back->damage_count() != 0) fail(to + ": " + back->damage().front().message);
    if (checked == 0) fail("nothing read back");
    return o;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) fail("usage: trace_store_bench TRACE [DIR]");
    const std::string from = argv[1];
    const std::string dir = argc > 2 ? argv[2] : "/dev/shm";
    const std::string to = dir + "/trace_store_bench_" + std::to_string(getpid()) + ".clt";
    ReferencedZstd peer;
    if (TraceError e = referenced_zstd(from, 0, {}, &peer)) fail(e.message);

    std::vector<Setting> settings;
    auto add = [&](const char* name, auto&& change, bool contents = true) {
        TraceWriterOptions o;
        o.zstd_level = peer.zstd_level;
        o.sync_on_finish = false;
        change(o);
        settings.push_back({name, o, contents});
    };
    add("one frame, whole contents (format 1.5)", [](TraceWriterOptions& o) {
        o.delta_contents = false;
        o.content_streams = false;
    });
    add("one frame, XOR deltas (format 1.7)",
        [](TraceWriterOptions& o) { o.content_streams = false; });
    add("streams, integers in planes (default)", [](TraceWriterOptions&) {});
    add("streams, every content as it is",
        [](TraceWriterOptions& o) { o.whole_content_planes = false; });
    add("streams, no deltas", [](TraceWriterOptions& o) { o.delta_contents = false; });
    add("XOR deltas as they are (byte planes off)",
        [](TraceWriterOptions& o) { o.delta_byte_planes = false; });
    add("XOR deltas, chain limit 16", [](TraceWriterOptions& o) { o.delta_chain_limit = 16; });
    add("XOR deltas, no chain limit", [](TraceWriterOptions& o) { o.delta_chain_limit = 0; });
    add("XOR deltas, 1 MiB of bases", [](TraceWriterOptions& o) { o.delta_base_bytes = 1u << 20; });
    add("XOR deltas, zstd window 4 MiB", [](TraceWriterOptions& o) { o.zstd_window_log = 22; });
    add("XOR deltas, 16 MiB chunks, window 16 MiB", [](TraceWriterOptions& o) {
        o.zstd_window_log = 24;
        o.chunk_raw_bytes = 16u << 20;
    });
    add(
        "records alone (no contents; for scale)", [](TraceWriterOptions&) {}, false);

    std::printf("%s: %llu snapshots, %llu bytes referenced; plain zstd -%d of them: %llu bytes\n\n",
                from.c_str(), (unsigned long long)peer.snapshots,
                (unsigned long long)peer.referenced_bytes, peer.zstd_level,
                (unsigned long long)peer.zstd_bytes);
    std::printf(
        "| storage                                    | trace bytes | vs zstd | contents whole / "
        "delta "
        "| write CPU s | read CPU s |\n"
        "|--------------------------------------------|------------:|--------:|--------------------"
        "---:"
        "|------------:|-----------:|\n");
    for (const Setting& s : settings) {
        const Outcome o = rewrite(from, to, s.options, s.contents);
        std::printf("| %-42s | %11llu | %6.2fx | %10llu / %9llu | %11.3f | %10.3f |\n", s.name,
                    (unsigned long long)o.file_bytes,
                    double(o.file_bytes) / double(peer.zstd_bytes),
                    (unsigned long long)(o.stats.contents_stored - o.stats.contents_delta_stored),
                    (unsigned long long)o.stats.contents_delta_stored, o.write_cpu_s, o.read_cpu_s);
        ::unlink(to.c_str());
    }
    return 0;
}
