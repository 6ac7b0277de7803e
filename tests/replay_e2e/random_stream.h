// SPDX-License-Identifier: Apache-2.0
// Random, correctly synchronized traces: cluster builds of every op type (scratch shared
// by all of them), copies, fills, updates and dispatches over the same buffers, on several
// queues handed over by semaphores, with host writes after fence waits.
//
// Why it is valid: between two consecutive commands of the stream there is always a
// dependency from the first one's stages (and writes) to the second one's stages (and
// accesses): a pipeline barrier, an event set/wait pair, or, when the stream moves to
// another queue, a semaphore whose signal stage mask holds the last command's stages.
// By induction every earlier access is then ordered before, and visible to, each command.
// Object references (BLAS over CLAS, instantiations of templates, moves) only name objects
// built explicitly at known addresses and not overwritten since.
#pragma once

#include <cstdint>
#include <string>

namespace clastrace::test {

struct RandomStreamOptions {
    uint64_t seed = 1;
    uint64_t min_cluster_ops = 10000;  // keep adding commands until the builds hold this many ops
    uint32_t queues = 3;
    // Per command, the chance of one hostile change (dropped dependency, damaged info,
    // count, stride or address): 0 writes a valid stream.
    double mutation_rate = 0;
};

struct RandomStreamStats {
    uint64_t cluster_ops = 0;
    uint64_t cluster_commands = 0;
    uint64_t commands = 0;  // every command, barriers included
    uint64_t submissions = 0;
    uint64_t command_buffers = 0;  // beyond one per submission
    uint64_t mutations = 0;
    uint64_t commands_by_op_type[6] = {};  // VkClusterAccelerationStructureOpTypeNV
    uint64_t events = 0, narrow_signals = 0, semaphores = 0, host_writes = 0;
};

RandomStreamStats write_random_stream(const std::string& path, const RandomStreamOptions& options);

}  // namespace clastrace::test
