// SPDX-License-Identifier: Apache-2.0
// The command, as named stages sharing one CommandState: resolve indirections and the op
// count, check buffer usage and scratch, run the ops chunk by chunk (reads in parallel,
// writes in op order), then check what only the whole command shows (overlaps, totals,
// intra-command hazards). The stages live in execute_resolve.cpp, execute_checks.cpp and
// execute_run.cpp.
#include "clastrace/engine/execute.h"
#include "execute_command.h"

#include <algorithm>

namespace clastrace::engine {

ExecutionRecord execute(const VkClusterAccelerationStructureCommandsInfoNV& command,
                        MemoryImage& memory, const ExecuteOptions& options) {
    using namespace detail;
    ExecutionRecord record;
    CommandState s(command, memory, options, record);
    if (!check_parameters(s) || !resolve_addresses(s)) return record;
    check_buffer_usage(s, UsageExtent::kFirstByte);
    resolve_op_count(s);
    check_buffer_usage(s, UsageExtent::kUsedElements);
    check_scratch(s);
    check_destinations(s);
    s.flush_command_findings();  // command-level findings come before the ops'

    run_ops(s);
    check_whole_command(s);
    check_intra_command_hazards(s);
    s.flush_command_findings();
    s.sink.close();
    record.accesses.reserve(s.top.accesses.size() + s.op_accesses.size());
    for (auto* part : {&s.top.accesses, &s.op_accesses})
        record.accesses.insert(record.accesses.end(), std::make_move_iterator(part->begin()),
                               std::make_move_iterator(part->end()));
    return record;
}

}  // namespace clastrace::engine
