// SPDX-License-Identifier: Apache-2.0
// An aligned plain-text table that never exceeds a given width: left-aligned columns are
// shortened (ending in "~") until the row fits.
#pragma once

#include <ostream>
#include <string>
#include <vector>

namespace clastrace::analyze {

class TextTable {
public:
    enum class Align { kLeft, kRight };
    TextTable& column(std::string header, Align align = Align::kRight);
    TextTable& row(std::vector<std::string> cells);
    void print(std::ostream& out, std::size_t max_width, const std::string& indent = "") const;
    bool empty() const { return rows_.empty(); }

private:
    std::vector<std::string> headers_;
    std::vector<Align> aligns_;
    std::vector<std::vector<std::string>> rows_;
};

}  // namespace clastrace::analyze
