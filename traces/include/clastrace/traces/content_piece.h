// SPDX-License-Identifier: Apache-2.0
// One part of a content handed to the writer in pieces (adjacent ranges read separately).
// Its own header because the writer's hashing kernels, compiled per instruction set, may
// include nothing that could emit shared inline code.
#pragma once

#include <cstddef>

namespace clastrace::traces {

struct ContentPiece {
    const void* bytes;
    size_t size;
};

}  // namespace clastrace::traces
