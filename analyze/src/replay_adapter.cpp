#include "clastrace/analyze/replay_adapter.h"

#include <map>
#include <tuple>
#include <vector>

#include <fmt/format.h>

#include "clastrace/replay/replay_report.hpp"

namespace clastrace::analyze {

namespace {

using CommandKey = std::tuple<uint32_t, uint32_t, uint32_t>;  // submission, command buffer, command

CommandKey key_of(const replay::ReplayLocation& w) { return {w.submission, w.command_buffer, w.command}; }
CommandKey key_of(const replay::CommandRef& c) { return {c.submission, c.command_buffer, c.command}; }

struct PendingCommand {
  replay::ReplayLocation where;
  const replay::SizeComparison* sizes = nullptr;
  std::vector<const replay::HazardReport*> hazards;
};

OpType op_type_of(uint32_t vk_op_type) {
  return vk_op_type < static_cast<uint32_t>(OpType::other) ? static_cast<OpType>(vk_op_type) : OpType::other;
}

ObjectType object_type_of(OpType t) {
  switch (t) {
    case OpType::build_triangle_cluster:
    case OpType::instantiate_triangle_cluster: return ObjectType::clas;
    case OpType::build_triangle_cluster_template: return ObjectType::cluster_template;
    case OpType::build_clusters_bottom_level: return ObjectType::blas;
    default: return ObjectType::other;
  }
}

}  // namespace

ReplayFeedStats feed_replay_report(const replay::ReplayReport& report, Analyzer& analyzer) {
  ReplayFeedStats stats;
  // The sequence number of a command is known wherever the report kept a ReplayLocation.
  std::map<CommandKey, uint64_t> sequence_of;
  std::map<uint64_t, PendingCommand> commands;  // by sequence
  for (const replay::SizeComparison& s : report.sizes) {
    sequence_of[key_of(s.where)] = s.where.sequence;
    PendingCommand& p = commands[s.where.sequence];
    p.where = s.where;
    p.sizes = &s;
  }
  for (const replay::ReplayFinding& f : report.findings) sequence_of.emplace(key_of(f.where), f.where.sequence);
  for (const replay::NotReplayed& n : report.not_replayed) sequence_of.emplace(key_of(n.where), n.where.sequence);

  for (const replay::HazardReport& h : report.hazards) {
    auto later = sequence_of.find(key_of(h.later.command));
    auto prior = sequence_of.find(key_of(h.prior.command));
    if (later == sequence_of.end() || prior == sequence_of.end() || prior->second > later->second) {
      ++stats.hazards_not_fed;
      continue;
    }
    PendingCommand& p = commands[later->second];
    if (!p.sizes) {  // a command the report knows only by this hazard
      p.where.sequence = later->second;
      p.where.submission = h.later.command.submission;
      p.where.command_buffer = h.later.command.command_buffer;
      p.where.command = h.later.command.command;
      p.where.command_buffer_handle = h.later.command.command_buffer_handle;
      p.where.name = h.later.command.name;
    }
    p.hazards.push_back(&h);
  }

  uint64_t last_submission = 0;
  for (const auto& [sequence, p] : commands) {
    if (p.where.submission < last_submission) {
      ++stats.commands_out_of_order;
      stats.hazards_not_fed += p.hazards.size();
      continue;
    }
    last_submission = p.where.submission;
    CommandInfo c;
    c.ordinal = sequence;
    c.submission = p.where.submission;
    c.command_buffer = p.where.command_buffer_handle;
    c.index = p.where.command;
    c.name = p.where.name ? p.where.name : "";
    if (p.sizes) {
      c.op_type = op_type_of(p.sizes->op_type);
      // The report does not keep the op mode; sizes are compared only where the capture
      // recorded dstSizesArray, which every mode but compute_sizes writes alongside objects.
      c.op_count = p.sizes->ops;
    }
    analyzer.on_command(c);
    ++stats.commands;
    if (p.sizes) {
      const ObjectType type = object_type_of(c.op_type);
      for (const replay::SizeComparison::OpSize& op : p.sizes->first_ops) {
        ObjectInfo o;
        o.op_index = op.op;
        o.type = type;
        o.engine_bytes = op.engine;
        o.driver_bytes = op.captured;
        analyzer.on_object(o);
        ++stats.objects;
      }
      if (p.sizes->ops > p.sizes->first_ops.size()) stats.ops_without_sizes += p.sizes->ops - p.sizes->first_ops.size();
    }
    for (const replay::HazardReport* h : p.hazards) {
      HazardSummary s;
      s.hazard_class = replay::hazard_class_name(h->hazard);
      s.first_command = sequence_of.at(key_of(h->prior.command));
      s.second_command = sequence;
      s.base = h->overlap.begin;
      s.size = h->overlap.empty() ? 0 : h->overlap.end - h->overlap.begin;
      s.message = h->format();
      analyzer.on_hazard(s);
      ++stats.hazards;
    }
  }
  return stats;
}

}  // namespace clastrace::analyze
