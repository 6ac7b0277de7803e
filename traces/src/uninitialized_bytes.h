// SPDX-License-Identifier: Apache-2.0
// Byte buffers whose growth leaves the new bytes uninitialized. The writer's chunk buffers,
// streams and compressed payloads are written over whole before anything reads them, so
// value-initializing them first (what std::vector<uint8_t>::resize does) would be one more pass
// over every chunk, and on fresh pages a fault for each.
#pragma once

#include "clastrace/common/uninitialized_allocator.h"

namespace clastrace::traces::format {

using common::UninitializedAllocator;
using common::UninitializedBytes;

}  // namespace clastrace::traces::format
