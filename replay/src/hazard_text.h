// SPDX-License-Identifier: Apache-2.0
// The pieces of text a hazard message and its advice share (hazard_report.cpp), so a command
// and a range read the same wherever replay names them.
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
