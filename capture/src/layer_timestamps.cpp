// SPDX-License-Identifier: Apache-2.0
// GPU timestamps around captured commands: the readback. Queries are read only once the
// application has learned the execution completed (a fence it waited for, an idle wait) or
// may no longer be pending (its command buffer is reset, freed or re-begun): a driver may
// implement any query read as a wait for the whole submission, which a paused queue never
// finishes (lavapipe does), so the pause worker cannot read them.
#include "layer_state.h"

#include <clastrace/capture/capture_cost.h>
#include <clastrace/capture/capture_records.h>

namespace clastrace::capture {

void read_completed_timestamps(
    DeviceState& d,
    const std::function<bool(const DeviceState::PendingTimestampRead&)>& completed) {
    std::vector<DeviceState::PendingTimestampRead> ready;
    {
        std::lock_guard lock(d.timestamps_mutex);
        auto& pending = d.pending_timestamp_reads;
        for (auto it = pending.begin(); it != pending.end();) {
            if (completed(*it)) {
                ready.push_back(*it);
                it = pending.erase(it);
            } else {
                ++it;
            }
        }
    }
    for (const auto& r : ready) {
        ClusterBuildCapture read;
        read.kind = CapturedCommandKind::kTimestamps;
        read.pause_id = r.read_pause_id;
        read.occurrence = r.occurrence;
        read.submission_index = r.submission_index;
        read.command_buffer = r.command_buffer;
        std::vector<uint64_t> results(size_t(r.count) * 2);  // (ticks, availability) per query
        // No WAIT: the execution is complete, so what is not available now never will be.
        const uint64_t started = wall_ns();
        const VkResult result = d.next.GetQueryPoolResults(
            d.device, r.pool, 0, r.count, results.size() * sizeof(uint64_t), results.data(),
            2 * sizeof(uint64_t), VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WITH_AVAILABILITY_BIT);
        add_cost(CostPhase::kTimestampRead, wall_ns() - started);
        const bool read_ok = result == VK_SUCCESS || result == VK_NOT_READY;
        for (uint32_t q = 0; q < r.count; ++q) {
            const bool valid = read_ok && results[2 * q + 1] != 0;
            read.timestamp_ticks.push_back(valid ? results[2 * q] & d.timestamp_mask : 0);
            read.timestamp_valid.push_back(valid);
        }
        if (!read_ok)
            log_message(
                LogLevel::kError,
                "reading the layer's timestamps of command buffer 0x%llx failed (VkResult %d)",
                (unsigned long long)r.command_buffer, int(result));
        if (d.capturing_now()) d.sink->cluster_build_captured(std::move(read));
    }
}

}  // namespace clastrace::capture
