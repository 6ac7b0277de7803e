// SPDX-License-Identifier: Apache-2.0
// The one text for a command and for a range in replay's messages (defined in
// hazard_report.cpp): hazards, their advice, the findings that name another command (a destroy
// or free while it is pending, a structure it reads that nothing built), and every finding's
// and note's own place, its header (ReplayFinding::format). With the two ways replay names a
// command, a CommandRef (the sync model's) and a ReplayLocation (a report's), and their
// conversions.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "clastrace/replay/replay_report.h"
#include "clastrace/replay/sync_types.h"

namespace clastrace::replay {

// Where a command ran: "NAME (queue Q, submit S, cb C, cmd N[, frame F][ > secondary I
// (0xHANDLE), cmd M])", or "NAME (host)" for the host's side (queue kHostQueue).
std::string command_place_text(const CommandRef& command, QueueId queue,
                               std::optional<uint64_t> frame = std::nullopt);
// A finding's or note's own place, as command_place_text names it with the command buffer's
// handle after its index and the sequence number --ops selects by: "NAME (queue Q, submit S, cb
// C (0xHANDLE), cmd N[ > secondary I (0xHANDLE), cmd M]) [#N]"; a call of the host's keeps
// the submission count its location has: "NAME (host, submit S) [#N]".
std::string finding_place_text(const ReplayLocation& where);
// "[0xBEGIN, 0xEND)".
std::string range_text(AddressRange range);

// The location of command `ref`, the sequence-th command replayed, on `queue`.
inline ReplayLocation location(const CommandRef& ref, uint64_t sequence, QueueId queue) {
    return ReplayLocation{sequence,
                          ref.submission,
                          ref.command_buffer,
                          ref.command,
                          ref.command_buffer_handle,
                          ref.name,
                          ref.secondary_handle,
                          ref.secondary,
                          ref.secondary_command,
                          queue};
}
// The command a location names: location()'s inverse (the sequence and the queue have no
// place in it).
inline CommandRef command_ref(const ReplayLocation& where) {
    return CommandRef{.submission = where.submission,
                      .command_buffer = where.command_buffer,
                      .command_buffer_handle = where.command_buffer_handle,
                      .command = where.command,
                      .name = where.name,
                      .secondary_handle = where.secondary_handle,
                      .secondary = where.secondary,
                      .secondary_command = where.secondary_command};
}

}  // namespace clastrace::replay
