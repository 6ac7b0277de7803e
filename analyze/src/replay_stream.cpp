// SPDX-License-Identifier: Apache-2.0
#include "clastrace/analyze/replay_stream.h"

#include <algorithm>
#include <deque>
#include <map>
#include <tuple>
#include <unordered_map>

#include <fmt/format.h>

#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>

#include "command_events.h"

namespace clastrace::analyze {

namespace {

using detail::HeldCommand;

uint64_t command_key(uint32_t submission, uint32_t command_buffer, uint32_t command,
                     uint64_t secondary_handle, uint32_t secondary, uint32_t secondary_command) {
    // 24 bits of command buffer and command: a hazard naming a command past that is unknown.
    uint64_t key = (uint64_t{submission} << 40) ^ (uint64_t{command_buffer & 0xfffff} << 20) ^
                   (command & 0xfffff);
    if (secondary_handle) {  // commands of one secondary share the primary's execute index: mix in their own
        uint64_t x = (uint64_t{secondary} << 32 | secondary_command) + 0x9e3779b97f4a7c15ull;
        x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
        x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
        key ^= x ^ (x >> 31);
    }
    return key;
}
template <class Where>
uint64_t command_key(const Where& w) {
    return command_key(w.submission, w.command_buffer, w.command, w.secondary_handle, w.secondary,
                       w.secondary_command);
}

}  // namespace

struct ReplayStreamFeeder::State {
    Analyzer& analyzer;
    double period_ns;
    bool period_known;
    std::function<bool(uint64_t, std::vector<uint8_t>*)> contents;
    StreamOptions options;
    StreamStats stats;

    detail::RecordedState recorded;
    std::unordered_map<uint64_t, detail::TemplateShape> templates;
    engine::ClusterBuilder builder;

    std::vector<HeldCommand> held;  // the submission being replayed
    std::size_t held_events = 0, held_bytes = 0;
    std::map<std::tuple<std::string, uint64_t, std::string, std::string>, std::size_t>
        hazard_fold;  // of held.back()

    std::unordered_map<uint64_t, uint64_t> sequence_of;  // command_key -> ordinal, for hazards
    std::deque<uint64_t> window;

    uint64_t contents_bytes = 0, referenced_bytes = 0;
    std::optional<GpuClock> clock;
    uint64_t timestamps_backwards = 0, timestamps_invalid = 0;
    std::map<std::string, uint64_t> findings_by_source;

    State(Analyzer& a, double period, bool known,
          std::function<bool(uint64_t, std::vector<uint8_t>*)> c, StreamOptions o)
        : analyzer(a),
          period_ns(period > 0 && period < 1e12 ? period : 1.0),
          period_known(known && period > 0 && period < 1e12),
          contents(std::move(c)),
          options(o) {}

    void remember(const replay::ReplayLocation& w) {
        sequence_of[command_key(w)] = w.sequence;
        window.push_back(command_key(w));
        if (window.size() > options.hazard_window_commands) {
            auto it = sequence_of.find(window.front());
            if (it != sequence_of.end()) sequence_of.erase(it);
            window.pop_front();
        }
    }
    void assign_gpu_time();
    void flush();
};

ReplayStreamFeeder::ReplayStreamFeeder(
    Analyzer& analyzer, double timestamp_period_ns, bool period_known,
    std::function<bool(uint64_t, std::vector<uint8_t>*)> contents, StreamOptions options)
    : state_(std::make_unique<State>(analyzer, timestamp_period_ns, period_known,
                                     std::move(contents), options)) {
    GpuClock clock;
    clock.timestamp_period_ns = state_->period_ns;
    clock.period_known = state_->period_known;
    state_->clock = clock;
}

ReplayStreamFeeder::~ReplayStreamFeeder() = default;

const StreamStats& ReplayStreamFeeder::stats() const { return state_->stats; }

void ReplayStreamFeeder::on_record(const traces::RecordView& view) {
    State& s = *state_;
    ++s.stats.records;
    const fbs::Record& r = *view.record;
    if (const auto c = traces::contents_record(r)) {  // whole or delta (format 1.7)
        s.contents_bytes += c->size();
        return;
    }
    traces::SnapshotLists lists = traces::record_snapshots(r);
    for (const traces::SnapshotVector* list : {lists.inputs, lists.outputs})
        if (list)
            for (const fbs::MemorySnapshot* snap : *list) s.referenced_bytes += snap->size();
    if (const auto* cal = r.body_as_CalibratedTimestamps()) {
        // The first calibration places every span on the host clock; later ones could drift-correct.
        if (!s.clock->calibration_ticks) {
            s.clock->calibration_ticks = cal->gpu_ticks();
            s.clock->calibration_host_ns = cal->cpu_nanoseconds();
            s.clock->calibration_max_deviation_ns = cal->max_deviation_ns();
        }
        return;
    }
    s.recorded.on_record(r);
}

void ReplayStreamFeeder::on_submission_begin(uint32_t) { ++state_->stats.submissions; }

void ReplayStreamFeeder::on_command(const replay::ReplayedCommand& command) {
    State& s = *state_;
    ++s.stats.commands;
    s.remember(command.where);
    s.held.emplace_back();
    s.hazard_fold.clear();
    detail::DescribeContext ctx{s.recorded, s.templates, s.builder,
                                s.options.untruncated_rebuilds_per_command, s.contents};
    detail::describe_command(command, ctx, &s.held.back());
    s.stats.untruncated_rebuilds += ctx.rebuilds;
    s.held_events += s.held.back().regions.size() + s.held.back().objects.size() + 1;
    s.held_bytes += s.held.back().held_bytes();
}

void ReplayStreamFeeder::on_finding(const replay::ReplayFinding& finding) {
    ++state_->stats.findings;
    ++state_->findings_by_source[replay::finding_source_name(finding.source)];
}

void ReplayStreamFeeder::on_hazard(const replay::HazardReport& h) {
    State& s = *state_;
    ++s.stats.hazards;
    if (s.held.empty()) return;  // hazards always follow their command's on_command
    HeldCommand& cmd = s.held.back();
    auto prior = s.sequence_of.find(command_key(h.prior.command));
    if (prior == s.sequence_of.end() || prior->second > cmd.info.ordinal) {
        ++s.stats.hazards_prior_unknown;
        return;
    }
    const std::string hazard_class = replay::hazard_class_name(h.hazard);
    auto key =
        std::make_tuple(hazard_class, prior->second, replay::hazard_field_family(h.prior.field),
                        replay::hazard_field_family(h.later.field));
    const uint64_t base = h.overlap.begin,
                   size = h.overlap.empty() ? 0 : h.overlap.end - h.overlap.begin;
    auto [it, inserted] = s.hazard_fold.emplace(key, cmd.hazards.size());
    if (!inserted) {
        HazardSummary& m = cmd.hazards[it->second];
        ++cmd.hazard_folds[it->second];
        ++s.stats.hazards_merged;
        if (m.size != 0 && size != 0) {
            const uint64_t lo = std::min(m.base, base), hi = std::max(m.base + m.size, base + size);
            m.base = lo;
            m.size = hi - lo;
        } else {
            m.size = 0;  // one range unknown: the merged range is unknown
        }
        return;
    }
    cmd.hazards.push_back(
        HazardSummary{hazard_class, prior->second, cmd.info.ordinal, base, size, h.format()});
    cmd.hazard_folds.push_back(0);
    ++s.held_events;
    s.held_bytes += sizeof(HazardSummary) + cmd.hazards.back().message.capacity();
}

// A pair of timestamps of one command buffer spans the commands recorded between them. The
// span's time is one command's GPU time only when that command is the only one doing work
// there (barriers and labels do none); otherwise it stays a span of several commands.
void ReplayStreamFeeder::State::assign_gpu_time() {
    std::optional<std::size_t> open;  // index of the last valid timestamp in this command buffer
    for (std::size_t i = 0; i < held.size(); ++i) {
        HeldCommand& h = held[i];
        if (open && held[*open].command_buffer_index != h.command_buffer_index) open.reset();
        if (h.kind != HeldCommand::Kind::kTimestamp) continue;
        if (!h.ticks_valid) {
            ++timestamps_invalid;
            open.reset();
            continue;
        }
        if (open) {
            const HeldCommand& start = held[*open];
            if (h.ticks < start.ticks) {
                ++timestamps_backwards;
            } else {
                GpuSpan span;
                std::size_t work = 0, only = 0;
                for (std::size_t k = *open + 1; k < i; ++k) {
                    const HeldCommand& c = held[k];
                    if (c.kind == HeldCommand::Kind::kTimestamp ||
                        c.kind == HeldCommand::Kind::kLabel)
                        continue;
                    if (span.commands == 0) span.first_ordinal = c.info.ordinal;
                    span.last_ordinal = c.info.ordinal;
                    ++span.commands;
                    span.ops += c.info.op_count;
                    span.triangles += c.info.triangles;
                    if (c.kind == HeldCommand::Kind::kWork) {
                        ++work;
                        only = k;
                    }
                }
                const double ns = static_cast<double>(h.ticks - start.ticks) * period_ns;
                span.gpu_ns = ns < 1.8e19 ? static_cast<uint64_t>(ns + 0.5) : UINT64_MAX;
                span.start_ticks = start.ticks;
                if (span.commands > 0) analyzer.on_gpu_span(span);
                if (work == 1) held[only].info.gpu_ns = span.gpu_ns;
            }
        }
        open = i;
    }
}

void ReplayStreamFeeder::State::flush() {
    if (held.empty()) return;
    stats.largest_submission_events =
        std::max<uint64_t>(stats.largest_submission_events, held_events);
    stats.peak_held_bytes = std::max<uint64_t>(stats.peak_held_bytes,
                                               held_bytes + held.capacity() * sizeof(HeldCommand));
    assign_gpu_time();
    for (HeldCommand& h : held) {
        if (h.kind == HeldCommand::Kind::kTimestamp || h.kind == HeldCommand::Kind::kLabel)
            continue;
        ++stats.commands_fed;
        analyzer.on_command(h.info);
        if (h.query) analyzer.on_build_sizes(*h.query);
        for (const RegionInfo& r : h.regions) analyzer.on_region(r);
        for (const ObjectInfo& o : h.objects) analyzer.on_object(o);
        for (std::size_t i = 0; i < h.hazards.size(); ++i) {
            if (h.hazard_folds[i])
                h.hazards[i].message +=
                    fmt::format(" (and {} more hazards like it in this command)",
                                h.hazard_folds[i]);
            analyzer.on_hazard(h.hazards[i]);
        }
    }
    held.clear();
    held.shrink_to_fit();  // the next submission may be small: give the memory back
    held_events = held_bytes = 0;
}

void ReplayStreamFeeder::on_submission_end(uint32_t) { state_->flush(); }

void ReplayStreamFeeder::finish(const traces::TraceReadStats& read) {
    State& s = *state_;
    s.flush();
    s.analyzer.on_gpu_clock(*s.clock);
    TraceBytes bytes;
    bytes.deduplicated = read.raw_bytes;
    // Raw: every snapshot carrying its own bytes instead of naming stored contents.
    bytes.raw = read.raw_bytes >= s.contents_bytes
                    ? read.raw_bytes - s.contents_bytes + s.referenced_bytes
                    : read.raw_bytes;
    bytes.compressed = read.compressed_bytes;
    s.analyzer.on_trace_bytes(bytes);
    if (s.stats.hazards_prior_unknown)
        s.analyzer.on_note(fmt::format(
            "{} hazards name an earlier command older than the last {} commands: not in the report "
            "(clastrace replay lists them)",
            s.stats.hazards_prior_unknown, s.options.hazard_window_commands));
    if (s.timestamps_backwards)
        s.analyzer.on_note(fmt::format(
            "{} GPU timestamps are earlier than the timestamp before them in their command buffer: "
            "no span measured",
            s.timestamps_backwards));
    if (s.timestamps_invalid)
        s.analyzer.on_note(
            fmt::format("{} GPU timestamps have no valid ticks (the query had no result)",
                        s.timestamps_invalid));
    if (!s.period_known && s.stats.commands > 0)
        s.analyzer.on_note("the trace header has no timestampPeriod: 1 ns per tick assumed");
    if (s.recorded.queries_dropped())
        s.analyzer.on_note(
            fmt::format("{} build-sizes queries past the first {} distinct inputs were matched by "
                        "op type and mode only",
                        s.recorded.queries_dropped(), detail::RecordedState::kMaxQueries));
    for (const auto& [source, n] : s.findings_by_source)
        s.analyzer.on_note(
            fmt::format("replay made {} {} findings (clastrace replay lists them)", n, source));
}

namespace {

// The replay's own limits (replay::is_replay_limit), counted by rule: notes, not findings.
std::string replay_limits_note(const replay::ReplayReport& r) {
    if (r.notes.empty() && r.notes_over_cap == 0) return "";
    std::map<std::string, uint64_t> by_rule;
    for (const replay::ReplayNote& n : r.notes) ++by_rule[n.rule];
    std::string rules;
    for (const auto& [rule, n] : by_rule)
        rules += fmt::format("{}{} x{}", rules.empty() ? "" : ", ", rule, n);
    return fmt::format(
        "replay met {} limit(s) of its own, not findings ({}{}; clastrace replay lists them)",
        r.notes.size() + r.notes_over_cap, rules,
        r.notes_over_cap ? fmt::format(", {} more not kept", r.notes_over_cap) : "");
}

}  // namespace

TraceAnalysis analyze_trace(traces::TraceReader& reader, const std::string& trace_name,
                            const AnalyzeOptions& options) {
    double period = 1.0;
    bool known = false;
    if (const fbs::TraceHeader* h = reader.header())
        if (h->device() && h->device()->timestamp_period_ns() > 0) {
            period = h->device()->timestamp_period_ns();
            known = true;
        }
    Analyzer analyzer(trace_name, options.limits);
    ReplayStreamFeeder feeder(
        analyzer, period, known,
        [&reader](uint64_t hash, std::vector<uint8_t>* out) {
            return !reader.read_contents(hash, out);
        },
        options.stream);
    replay::ReplayOptions replay_options = options.replay;
    replay_options.observer = &feeder;
    TraceAnalysis result;
    result.replay = replay::replay_trace(reader, trace_name, replay_options);
    feeder.finish(reader.stats());
    if (result.replay.hazards_over_cap)
        analyzer.on_note(fmt::format(
            "{} hazards past replay's cap of {} distinct hazards were counted by replay only "
            "(not in this report)",
            result.replay.hazards_over_cap, replay_options.max_findings));
    if (const std::string limits = replay_limits_note(result.replay); !limits.empty())
        analyzer.on_note(limits);
    if (!result.replay.trace_damage.empty())
        analyzer.on_note(fmt::format(
            "the trace is damaged ({} problems; clastrace info lists them): the report covers what "
            "could be read",
            result.replay.trace_damage.size()));
    result.report = analyzer.finish();
    result.stream = feeder.stats();
    return result;
}

}  // namespace clastrace::analyze
