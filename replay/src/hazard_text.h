// SPDX-License-Identifier: Apache-2.0
// The one text for a command and for a range in replay's messages (defined in
// hazard_report.cpp): hazards, their advice, and the findings that name another command (a
// destroy or free while it is pending, a structure it reads that nothing built). A finding's
// own place, its header (ReplayFinding::format), is its record's, with the handle and [#N].
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "clastrace/replay/sync_types.h"

namespace clastrace::replay {

// Where a command ran: "NAME (queue Q, submit S, cb C, cmd N[, frame F][ > secondary I
// (0xHANDLE), cmd M])", or "NAME (host)" for the host's side (queue kHostQueue).
std::string command_place_text(const CommandRef& command, QueueId queue,
                               std::optional<uint64_t> frame = std::nullopt);
// "[0xBEGIN, 0xEND)".
std::string range_text(AddressRange range);

}  // namespace clastrace::replay
