// SPDX-License-Identifier: Apache-2.0
// The stages of engine::execute and the state of one command they share. execute() runs
// them in order: resolve the command, buffer-usage checks, scratch checks, running the
// ops, whole-command checks, intra-command hazards.
#pragma once

#include "execute_internal.h"

#include <map>

namespace clastrace::engine::detail {

// Keeps at most `cap` findings per rule; counts the rest.
struct FindingSink {
    std::vector<Finding>& out;
    uint32_t cap;
    std::map<std::string, uint64_t> counts;
    void add(Finding f);
    void close();  // one kRuleFindingsTruncated finding per rule over the cap
};

// A byte range an op wrote (or a move read), for the overlap checks.
struct Written {
    uint64_t begin, end;
    int64_t op;
};

struct CommandState {
    CommandState(const VkClusterAccelerationStructureCommandsInfoNV& command, MemoryImage& memory,
                 const ExecuteOptions& options, ExecutionRecord& record);

    const VkClusterAccelerationStructureInputInfoNV& input;
    const VkClusterAccelerationStructureCommandsInfoNV& command;
    MemoryImage& memory;
    const ExecuteOptions& options;
    ExecutionRecord& record;
    FindingSink sink;
    Recorder top;  // the command's own accesses and findings (op index -1)
    ObjectDirectory local_directory;
    ObjectDirectory& directory;  // options.directory, else local_directory
    ResolvedCommand cmd;

    bool implicit = false, explicit_mode = false, sizes_only = false, is_move = false;
    uint64_t align = 0;          // destination alignment of the command's objects
    bool scratch_usable = true;  // false once the scratch table cannot be written

    // Filled while the ops run.
    std::vector<MemoryAccess> op_accesses;
    std::vector<Written> written;  // destination objects
    std::vector<Written> move_sources;
    uint64_t cursor = 0;  // implicit packing offset
    uint64_t moved_bytes = 0, total_triangles = 0, total_vertices = 0, total_clusters = 0;

    // Hands the command's findings so far to the sink, keeping their order.
    void flush_command_findings();
};

// Resolve the command. Each returns false when nothing more is to be done: the record
// holds what was found.
bool check_parameters(CommandState& s);   // opType / opMode / opInput pointer
bool resolve_addresses(CommandState& s);  // indirected fields, 10445
void resolve_op_count(CommandState& s);   // srcInfosCount, stride, what srcInfosArray holds

// Buffer usage (12304-12308): the rows of one extent, in table order.
enum class UsageExtent {
    kFirstByte,     // the address's buffer (known before the op count)
    kUsedElements,  // every byte of the elements the ops use (needs the op count)
};
void check_buffer_usage(CommandState& s, UsageExtent extent);

void check_scratch(CommandState& s);       // 12300, 12301
void check_destinations(CommandState& s);  // alignment of dstImplicitData, the sizes array

void run_ops(CommandState& s);  // reads in parallel, writes in op order, chunk by chunk

void check_whole_command(CommandState& s);  // overlaps, moved bytes, totals
void check_intra_command_hazards(CommandState& s);

}  // namespace clastrace::engine::detail
