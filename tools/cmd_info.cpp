// SPDX-License-Identifier: Apache-2.0
// clastrace info TRACE [--json] [--vs-zstd]: what a trace holds and whether it is intact.
#include "commands.h"
#include "json_output.h"
#include "reader_options.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/records.h>
#include <clastrace/traces/referenced_zstd.h>
#include <clastrace/traces/trace_reader.h>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cstdio>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace clastrace::tools {

namespace {

using traces::TraceReader;

struct TraceSummary {
    std::array<uint64_t, traces::kRecordKindCount> by_kind{};
    uint64_t unknown_kinds = 0;
    uint64_t records = 0;
    uint64_t snapshots = 0;
    uint64_t bytes_referenced = 0;
    uint64_t contents = 0;
    uint64_t bytes_stored = 0;
    uint64_t delta_contents = 0;  // of contents: MemoryContentsDelta records
    uint64_t delta_bytes = 0;
    // --vs-zstd: plain zstd of the referenced bytes, or why it could not be had.
    std::optional<traces::ReferencedZstd> vs_zstd;
    std::string vs_zstd_error;
    // What the capture layer saw broken (CaptureFinding, format 1.1); the first kMaxListed kept.
    struct Finding {
        uint64_t submission, command_buffer;
        uint32_t command_index, op_index;
        uint8_t severity;
        std::string rule, message;
        uint64_t primary_command_buffer =
            0;  // format 1.2: the primary that ran this secondary's command
        uint32_t execute_command_index = 0;
    };
    static constexpr size_t kMaxListed = 1000;
    std::vector<Finding> findings;
    uint64_t finding_count = 0;
    // Frames (QueuePresent, format 1.2; FrameBoundary frame-end marks, format 1.4): a submission
    // belongs to the frame the next present or mark ends (the last one's frame + 1 after it).
    uint64_t presents = 0;
    uint64_t frame_marks = 0;  // FrameBoundary records with VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT
    uint64_t frame_ends() const { return presents + frame_marks; }
    uint64_t acquires = 0;  // AcquireNextImage records (format 1.2)
    uint64_t first_frame = 0, last_frame = 0;
    uint64_t unassigned_submissions = 0;  // QueueSubmits since the last present
    std::map<uint64_t, uint64_t> submissions_by_frame;
    // The layer's PreRangeState record: the trace starts with a frame range's state from before
    // it; its prelude submission belongs to no frame.
    bool pre_range = false;
    uint64_t pre_range_first_frame = 0, pre_range_bytes = 0, prelude_submission = 0;
    uint32_t pre_range_structures = 0, pre_range_commands = 0, pre_range_cluster_commands = 0;
};

const char* severity_name(uint8_t severity) {
    return severity == 0 ? "info" : severity == 1 ? "warning" : "error";
}

// The layer's record before a frame range's prelude (capture/README.md, "Frame ranges").
void read_pre_range_state(const fbs::PreRangeState& state, TraceSummary& s) {
    s.pre_range = true;
    s.pre_range_structures = state.structures();
    s.pre_range_commands = state.commands();
    s.pre_range_cluster_commands = state.cluster_commands();
    s.pre_range_bytes = state.input_bytes();
    s.pre_range_first_frame = state.before_frame();
    s.prelude_submission = state.prelude_submission();
}

TraceSummary summarize(TraceReader& reader) {
    TraceSummary s;
    traces::RecordView view;
    while (reader.next(&view)) {
        ++s.records;
        auto k = static_cast<unsigned>(view.kind);
        if (k < traces::kRecordKindCount) {
            ++s.by_kind[k];
        } else {
            ++s.unknown_kinds;
        }
        if (const auto* f = view.record->body_as_CaptureFinding()) {
            if (s.finding_count++ < TraceSummary::kMaxListed)
                s.findings.push_back({f->submission(), f->command_buffer(), f->command_index(),
                                      f->op_index(), f->severity(),
                                      f->rule() ? f->rule()->str() : "",
                                      f->message() ? f->message()->str() : "",
                                      f->primary_command_buffer(), f->execute_command_index()});
            continue;
        }
        if (const auto* state = view.record->body_as_PreRangeState()) {
            read_pre_range_state(*state, s);
            continue;
        }
        if (const auto* submit = view.record->body_as_QueueSubmit();
            submit && s.pre_range && submit->submission_index() == s.prelude_submission)
            continue;
        if (view.kind == fbs::RecordBody::QueueSubmit) ++s.unassigned_submissions;
        if (view.kind == fbs::RecordBody::AcquireNextImage) ++s.acquires;
        const auto* present = view.record->body_as_QueuePresent();
        const auto* mark = view.record->body_as_FrameBoundary();
        if (present || (mark && (mark->flags() & 1u))) {
            const uint64_t frame = present ? present->frame() : mark->frame();
            if (s.frame_ends() == 0) s.first_frame = frame;
            ++(present ? s.presents : s.frame_marks);
            s.last_frame = std::max(s.last_frame, frame);
            if (s.unassigned_submissions) s.submissions_by_frame[frame] += s.unassigned_submissions;
            s.unassigned_submissions = 0;
            continue;
        }
        if (const std::optional<traces::ContentsRecord> c = traces::contents_record(*view.record)) {
            ++s.contents;
            s.bytes_stored += c->size();
            if (c->delta) {
                ++s.delta_contents;
                s.delta_bytes += c->size();
            }
            continue;
        }
        traces::SnapshotLists lists = traces::record_snapshots(*view.record);
        for (const traces::SnapshotVector* list : {lists.inputs, lists.outputs}) {
            if (!list) continue;
            for (const auto* snap : *list) {
                ++s.snapshots;
                s.bytes_referenced += snap->size();
            }
        }
    }
    if (s.frame_ends() && s.unassigned_submissions)
        s.submissions_by_frame[s.last_frame + 1] += s.unassigned_submissions;
    return s;
}

std::string version_string(uint32_t v) {
    return fmt::format("{}.{}.{}", (v >> 22) & 0x7f, (v >> 12) & 0x3ff,
                       v & 0xfff);  // VK_API_VERSION_*
}

// NVIDIA packs its driver version 10.8.8.6 bits; everyone else uses the Vulkan packing.
std::string driver_string(uint32_t vendor, uint32_t v) {
    if (vendor == 0x10de)
        return fmt::format("{}.{}.{}", v >> 22, (v >> 14) & 0xff, (v >> 6) & 0xff);
    return version_string(v);
}

double ratio(uint64_t a, uint64_t b) {
    return b == 0 ? 0.0 : static_cast<double>(a) / static_cast<double>(b);
}

const char* str(const flatbuffers::String* s) { return s ? s->c_str() : ""; }

// The capture layer advertised the cluster feature and its engine executed the cluster builds
// (the trace names the engine as the driver), whatever the driver has.
bool served(const fbs::DeviceInfo* d) {
    return d->driver_name() && replay::is_engine_device(d->driver_name()->str());
}

nlohmann::json header_json(const fbs::TraceHeader* h) {
    using nlohmann::json;
    if (!h) return nullptr;
    json j;
    if (const auto* d = h->device()) {
        json dev = {{"name", str(d->name())},
                    {"vendor_id", d->vendor_id()},
                    {"device_id", d->device_id()},
                    {"driver_version", d->driver_version()},
                    {"driver_version_text", driver_string(d->vendor_id(), d->driver_version())},
                    {"api_version", d->api_version()},
                    {"api_version_text", version_string(d->api_version())},
                    {"driver_name", str(d->driver_name())},
                    {"driver_info", str(d->driver_info())}};
        json exts = json::array();
        if (d->enabled_extensions())
            for (const auto* e : *d->enabled_extensions()) exts.push_back(e->str());
        dev["enabled_extensions"] = exts;
        if (const auto* f = d->cluster_features()) {
            dev["cluster_features"] = {{"supported", f->cluster_acceleration_structure_supported()},
                                       {"enabled", f->cluster_acceleration_structure_enabled()},
                                       {"served", served(d)}};
        } else {
            dev["cluster_features"] = nullptr;
        }
        if (const auto* p = d->cluster_properties()) {
            dev["cluster_properties"] = {
                {"maxVerticesPerCluster", p->max_vertices_per_cluster()},
                {"maxTrianglesPerCluster", p->max_triangles_per_cluster()},
                {"clusterScratchByteAlignment", p->cluster_scratch_byte_alignment()},
                {"clusterByteAlignment", p->cluster_byte_alignment()},
                {"clusterTemplateByteAlignment", p->cluster_template_byte_alignment()},
                {"clusterBottomLevelByteAlignment", p->cluster_bottom_level_byte_alignment()},
                {"clusterTemplateBoundsByteAlignment", p->cluster_template_bounds_byte_alignment()},
                {"maxClusterGeometryIndex", p->max_cluster_geometry_index()}};
        } else {
            dev["cluster_properties"] = nullptr;
        }
        j["device"] = dev;
    } else {
        j["device"] = nullptr;
    }
    if (const auto* c = h->capture()) {
        j["capture"] = {{"application_name", str(c->application_name())},
                        {"engine_name", str(c->engine_name())},
                        {"capture_tool", str(c->capture_tool())},
                        {"start_time_unix_ns", c->start_time_unix_ns()},
                        {"snapshot_policy", str(c->snapshot_policy())},
                        {"chunk_raw_bytes", c->chunk_raw_bytes()},
                        {"zstd_level", c->zstd_level()},
                        {"content_hash_bits", c->content_hash_bits()}};
    } else {
        j["capture"] = nullptr;
    }
    return j;
}

nlohmann::json findings_json(const TraceSummary& s) {
    nlohmann::json items = nlohmann::json::array();
    for (const auto& f : s.findings) {
        items.push_back({{"submission", f.submission},
                         {"command_buffer", f.command_buffer},
                         {"command_index", f.command_index},
                         {"op_index", f.op_index == 0xFFFFFFFFu ? nlohmann::json(nullptr)
                                                                : nlohmann::json(f.op_index)},
                         {"severity", severity_name(f.severity)},
                         {"rule", f.rule},
                         {"message", f.message}});
        if (f.primary_command_buffer)
            items.back()["executed_by"] = {{"command_buffer", f.primary_command_buffer},
                                           {"execute_command_index", f.execute_command_index}};
    }
    return items;
}

nlohmann::json frames_json(const TraceSummary& s) {
    if (s.frame_ends() == 0 && s.acquires == 0) return {{"presents", 0}};
    if (s.frame_ends() == 0) return {{"presents", 0}, {"acquires", s.acquires}};
    nlohmann::json captured = nlohmann::json::array();
    for (const auto& [frame, submissions] : s.submissions_by_frame)
        captured.push_back({{"frame", frame}, {"submissions", submissions}});
    nlohmann::json frames = {{"presents", s.presents}, {"frame_marks", s.frame_marks},
                             {"acquires", s.acquires}, {"first", s.first_frame},
                             {"last", s.last_frame},   {"with_submissions", captured}};
    if (s.pre_range)
        frames["pre_range_state"] = {{"before_frame", s.pre_range_first_frame},
                                     {"structures", s.pre_range_structures},
                                     {"commands", s.pre_range_commands},
                                     {"cluster_commands", s.pre_range_cluster_commands},
                                     {"prelude_submission", s.prelude_submission},
                                     {"bytes", s.pre_range_bytes}};
    return frames;
}

// The file's size against plain zstd of its referenced bytes (null without --vs-zstd).
nlohmann::json size_vs_zstd_json(uint64_t file_size, const TraceSummary& s) {
    if (!s.vs_zstd && s.vs_zstd_error.empty()) return nullptr;
    if (!s.vs_zstd) return {{"error", s.vs_zstd_error}};
    return {{"file_bytes", file_size},
            {"zstd_bytes", s.vs_zstd->zstd_bytes},
            {"zstd_level", s.vs_zstd->zstd_level},
            {"ratio", ratio(file_size, s.vs_zstd->zstd_bytes)}};
}

nlohmann::json info_json(const std::string& path, const TraceReader& reader,
                         const TraceSummary& s) {
    using nlohmann::json;
    const traces::TraceReadStats& st = reader.stats();
    json by_kind = json::object();
    for (unsigned k = 1; k < traces::kRecordKindCount; ++k) {
        by_kind[traces::record_kind_name(static_cast<fbs::RecordBody>(k))] = s.by_kind[k];
    }
    json damage = json::array();
    for (const traces::TraceError& e : reader.damage()) {
        damage.push_back({{"code", traces::trace_error_code_name(e.code)},
                          {"offset", e.file_offset},
                          {"message", e.message}});
    }
    return {
        {"file", path},
        {"file_size", st.file_size},
        {"format_version", {{"major", reader.version_major()}, {"minor", reader.version_minor()}}},
        {"header", header_json(reader.header())},
        {"index",
         {{"present", reader.has_index()}, {"submissions", reader.indexed_submission_count()}}},
        {"records",
         {{"total", s.records},
          {"damaged", st.records_damaged},
          {"unknown_kind", s.unknown_kinds},
          {"by_kind", by_kind}}},
        {"memory",
         {{"snapshots", s.snapshots},
          {"bytes_referenced", s.bytes_referenced},
          {"contents", s.contents},
          {"bytes_stored", s.bytes_stored},
          {"contents_delta", s.delta_contents},
          {"bytes_stored_as_delta", s.delta_bytes},
          {"dedup_ratio", ratio(s.bytes_referenced, s.bytes_stored)}}},
        {"size_vs_zstd", size_vs_zstd_json(st.file_size, s)},
        {"chunks",
         {{"read", st.chunks_read},
          {"damaged", st.chunks_damaged},
          {"raw_bytes", st.raw_bytes},
          {"compressed_bytes", st.compressed_bytes},
          {"compression_ratio", ratio(st.raw_bytes, st.compressed_bytes)},
          {"bytes_skipped", st.bytes_skipped}}},
        {"damage", {{"count", reader.damage_count()}, {"items", damage}}},
        {"capture_findings", {{"count", s.finding_count}, {"items", findings_json(s)}}},
        {"frames", frames_json(s)},
    };
}

// The device and capture lines of the trace's header.
void print_header(const TraceReader& reader) {
    if (const fbs::TraceHeader* h = reader.header()) {
        if (const auto* d = h->device()) {
            fmt::print("{:<12}{} (vendor {:#06x}, device {:#06x}), driver {} {}, Vulkan {}\n",
                       "device", str(d->name()), d->vendor_id(), d->device_id(),
                       str(d->driver_name()), driver_string(d->vendor_id(), d->driver_version()),
                       version_string(d->api_version()));
            if (const auto* f = d->cluster_features()) {
                fmt::print("{:<12}clusterAccelerationStructure supported {}, enabled {}{}\n",
                           "clusters", f->cluster_acceleration_structure_supported() ? "yes" : "no",
                           f->cluster_acceleration_structure_enabled() ? "yes" : "no",
                           served(d) ? " (served: the capture layer advertised it and clastrace's "
                                       "engine ran the cluster "
                                       "builds, not the driver)"
                                     : "");
            }
            if (const auto* p = d->cluster_properties()) {
                fmt::print(
                    "{:<12}maxVerticesPerCluster {}, maxTrianglesPerCluster {}, "
                    "maxClusterGeometryIndex {}\n",
                    "", p->max_vertices_per_cluster(), p->max_triangles_per_cluster(),
                    p->max_cluster_geometry_index());
                fmt::print(
                    "{:<12}alignments: scratch {}, cluster {}, template {}, bottom level {}, "
                    "template bounds {}\n",
                    "", p->cluster_scratch_byte_alignment(), p->cluster_byte_alignment(),
                    p->cluster_template_byte_alignment(), p->cluster_bottom_level_byte_alignment(),
                    p->cluster_template_bounds_byte_alignment());
            }
        }
        if (const auto* c = h->capture()) {
            fmt::print(
                "{:<12}application \"{}\", tool \"{}\", snapshots \"{}\", chunks of {} bytes, zstd "
                "level {}\n",
                "capture", str(c->application_name()), str(c->capture_tool()),
                str(c->snapshot_policy()), c->chunk_raw_bytes(), c->zstd_level());
        }
    } else {
        fmt::print("{:<12}(damaged)\n", "header");
    }
}

// Records by kind.
void print_records(const TraceReader& reader, const TraceSummary& s) {
    const traces::TraceReadStats& st = reader.stats();
    fmt::print("\n{:<46}{:>10}\n", "record kind", "count");
    for (unsigned k = 1; k < traces::kRecordKindCount; ++k) {
        if (s.by_kind[k] == 0) continue;
        fmt::print("  {:<44}{:>10}\n", traces::record_kind_name(static_cast<fbs::RecordBody>(k)),
                   s.by_kind[k]);
    }
    if (s.unknown_kinds) fmt::print("  {:<44}{:>10}\n", "(newer kinds, skipped)", s.unknown_kinds);
    fmt::print("  {:<44}{:>10}\n", "total", s.records);
    if (st.records_damaged) fmt::print("  {:<44}{:>10}\n", "damaged (skipped)", st.records_damaged);
}

// Frames, the state from before the range, acquires.
void print_frames(const TraceSummary& s) {
    if (s.frame_ends()) {
        const std::string ends =
            s.frame_marks == 0 ? fmt::format("{} presents", s.presents)
            : s.presents == 0
                ? fmt::format("{} frame-end marks", s.frame_marks)
                : fmt::format("{} presents and {} frame-end marks", s.presents, s.frame_marks);
        fmt::print("\n{:<12}{}, ending frames {}-{}; submissions in frames:", "frames", ends,
                   s.first_frame, s.last_frame);
        size_t listed = 0;
        for (const auto& [frame, submissions] : s.submissions_by_frame) {
            if (listed++ == 32) {
                fmt::print(" ... ({} frames in all)", s.submissions_by_frame.size());
                break;
            }
            fmt::print(" {} ({})", frame, submissions);
        }
        fmt::print("{}\n", s.submissions_by_frame.empty() ? " none" : "");
    }
    if (s.pre_range)
        fmt::print(
            "{:<12}the trace starts with the state from before the range: {} acceleration "
            "structures rebuilt by {} commands ({} cluster builds; {} input bytes) from "
            "before frame {}, prelude submission {}\n",
            "pre-range", s.pre_range_structures, s.pre_range_commands, s.pre_range_cluster_commands,
            s.pre_range_bytes, s.pre_range_first_frame, s.prelude_submission);
    // Acquires (format 1.2): the presentation engine's signals replay takes for the frames' waits.
    if (s.acquires)
        fmt::print("{}{:<12}{} image acquires\n", s.frame_ends() ? "" : "\n",
                   s.frame_ends() ? "" : "frames", s.acquires);
}

// What the layer found while capturing.
void print_capture_findings(const TraceSummary& s) {
    if (s.finding_count) {
        fmt::print("\n{:<12}{} recorded while capturing\n", "findings", s.finding_count);
        for (const auto& f : s.findings) {
            std::string op = f.op_index == 0xFFFFFFFFu ? "" : fmt::format(" op {}", f.op_index);
            if (f.primary_command_buffer)  // a secondary's command: which primary ran it
                op += fmt::format(" (executed by {:#x} command {})", f.primary_command_buffer,
                                  f.execute_command_index);
            const std::string command = f.command_index == 0xFFFFFFFFu
                                            ? std::string("(whole)")
                                            : std::to_string(f.command_index);
            fmt::print("  submission {} command buffer {:#x} command {}{}: [{}] {}: {}\n",
                       f.submission, f.command_buffer, command, op, severity_name(f.severity),
                       f.rule, f.message);
        }
        if (s.finding_count > s.findings.size())
            fmt::print("  ... {} more not listed\n", s.finding_count - s.findings.size());
    }
}

// Contents, size against zstd, chunks and damage.
void print_storage(const TraceReader& reader, const TraceSummary& s) {
    const traces::TraceReadStats& st = reader.stats();
    fmt::print(
        "\n{:<12}{} bytes referenced by {} snapshots, {} bytes stored in {} contents, dedup ratio "
        "{:.2f}x\n",
        "memory", s.bytes_referenced, s.snapshots, s.bytes_stored, s.contents,
        ratio(s.bytes_referenced, s.bytes_stored));
    if (s.delta_contents)
        fmt::print("{:<12}{} contents ({} bytes) stored XOR an earlier content of their range\n",
                   "", s.delta_contents, s.delta_bytes);
    if (s.vs_zstd)
        fmt::print("{:<12}{} bytes = {:.2f}x plain zstd -{} of the referenced bytes ({} bytes)\n",
                   "size", st.file_size, ratio(st.file_size, s.vs_zstd->zstd_bytes),
                   s.vs_zstd->zstd_level, s.vs_zstd->zstd_bytes);
    else if (!s.vs_zstd_error.empty())
        fmt::print("{:<12}not compared with zstd: {}\n", "size", s.vs_zstd_error);
    fmt::print(
        "{:<12}{} read, {} damaged; {} raw bytes, {} compressed bytes, compression ratio {:.2f}x\n",
        "chunks", st.chunks_read, st.chunks_damaged, st.raw_bytes, st.compressed_bytes,
        ratio(st.raw_bytes, st.compressed_bytes));
    if (reader.damage_count() == 0) {
        fmt::print("{:<12}none\n", "damage");
        return;
    }
    fmt::print("{:<12}{} problem(s)\n", "damage", reader.damage_count());
    for (const traces::TraceError& e : reader.damage()) {
        fmt::print("  [{}] {}\n", traces::trace_error_code_name(e.code), e.message);
    }
    if (reader.damage_count() > reader.damage().size()) {
        fmt::print("  ... {} more not listed\n", reader.damage_count() - reader.damage().size());
    }
}

void print_text(const std::string& path, const TraceReader& reader, const TraceSummary& s) {
    const traces::TraceReadStats& st = reader.stats();
    fmt::print("{:<12}{} ({} bytes)\n", "trace", path, st.file_size);
    fmt::print("{:<12}{}.{}\n", "format", reader.version_major(), reader.version_minor());
    print_header(reader);
    fmt::print("{:<12}{}\n", "index",
               reader.has_index()
                   ? fmt::format("present, {} submissions", reader.indexed_submission_count())
                   : std::string("absent"));

    print_records(reader, s);
    print_frames(s);
    print_capture_findings(s);
    print_storage(reader, s);
}

}  // namespace

Command register_info(CLI::App& app) {
    struct Options {
        std::string path;
        bool json = false;
        bool vs_zstd = false;
        traces::TraceReaderOptions reader{.verify_content_keys = true};
    };
    auto options = std::make_shared<Options>();
    CLI::App* sub = app.add_subcommand(
        "info",
        "Show a trace's header, record counts, memory deduplication, compression and any damage.\n"
        "Exit code: 0 intact, 1 damage found, 2 usage error or unreadable file.");
    sub->add_option("TRACE", options->path, "the .clt trace file")->required();
    sub->add_flag("--json", options->json,
                  "print one JSON object (fields in docs/trace-format.md)");
    sub->add_flag("--vs-zstd", options->vs_zstd,
                  "also compress the bytes the snapshots reference with plain zstd at the trace's "
                  "level and print the file's size against it (reads every snapshot's bytes: "
                  "about 0.3 s per 100 MB referenced)");
    add_max_raw_option(sub, &options->reader);

    auto run = [options]() -> int {
        traces::TraceError error;
        std::unique_ptr<TraceReader> reader =
            TraceReader::open(options->path, &error, options->reader);
        if (!reader) {
            if (options->json) {
                nlohmann::json j = {{"file", options->path},
                                    {"error",
                                     {{"code", traces::trace_error_code_name(error.code)},
                                      {"offset", error.file_offset},
                                      {"message", error.message}}}};
                std::cout << json_text(j) << "\n";
            }
            std::fprintf(stderr, "clastrace info: %s\n", error.message.c_str());
            return kExitUsage;
        }
        TraceSummary summary = summarize(*reader);
        if (options->vs_zstd) {
            traces::ReferencedZstd peer;
            traces::TraceError e =
                traces::referenced_zstd(options->path, 0, options->reader, &peer);
            if (e)
                summary.vs_zstd_error = e.message;
            else
                summary.vs_zstd = peer;
        }
        if (options->json) {
            std::cout << json_text(info_json(options->path, *reader, summary)) << "\n";
        } else {
            print_text(options->path, *reader, summary);
        }
        return reader->damage_count() == 0 ? kExitOk : kExitFindings;
    };
    return {sub, run};
}

}  // namespace clastrace::tools
