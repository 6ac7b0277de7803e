// SPDX-License-Identifier: Apache-2.0
// Copies out of host-visible memory that is not HOST_CACHED (on NVIDIA the first
// HOST_VISIBLE|HOST_COHERENT type is write-combined system memory): ordinary loads there are
// uncached, one line at a time, and run at a few GB/s; SSE4.1 streaming loads (MOVNTDQA) fetch
// whole lines into the streaming buffers and run several times faster. The capture reads every
// input range of a build this way while the queue waits. Falls back to memcpy on small copies
// and on processors without SSE4.1; on cached memory the result is the same bytes either way.
#pragma once

#include <cstddef>
#include <cstdint>

namespace clastrace::capture {

void copy_from_uncached(uint8_t* destination, const uint8_t* source, size_t size);

}  // namespace clastrace::capture
