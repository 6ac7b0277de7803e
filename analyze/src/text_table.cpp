#include "text_table.h"

#include <algorithm>

namespace clastrace::analyze {

TextTable& TextTable::column(std::string header, Align align) {
  headers_.push_back(std::move(header));
  aligns_.push_back(align);
  return *this;
}

TextTable& TextTable::row(std::vector<std::string> cells) {
  cells.resize(headers_.size());
  // Labels and messages come from the trace: a newline or tab would break the alignment.
  for (auto& cell : cells)
    for (char& ch : cell)
      if (static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f) ch = '?';
  rows_.push_back(std::move(cells));
  return *this;
}

static std::string fit(const std::string& s, std::size_t width) {
  if (s.size() <= width) return s;
  if (width == 0) return {};
  return s.substr(0, width - 1) + "~";
}

void TextTable::print(std::ostream& out, std::size_t max_width, const std::string& indent) const {
  const std::size_t n = headers_.size();
  std::vector<std::size_t> width(n);
  for (std::size_t c = 0; c < n; ++c) {
    width[c] = headers_[c].size();
    for (const auto& r : rows_) width[c] = std::max(width[c], r[c].size());
  }
  auto total = [&] {
    std::size_t t = indent.size();
    for (std::size_t c = 0; c < n; ++c) t += width[c] + (c ? 2 : 0);
    return t;
  };
  // Shrink the widest left-aligned column (text such as names and labels) until it fits.
  while (total() > max_width) {
    std::size_t widest = n;
    for (std::size_t c = 0; c < n; ++c)
      if (aligns_[c] == Align::left && width[c] > 4 && (widest == n || width[c] > width[widest])) widest = c;
    if (widest == n) break;
    --width[widest];
  }
  auto line = [&](const std::vector<std::string>& cells) {
    std::string s = indent;
    for (std::size_t c = 0; c < n; ++c) {
      std::string cell = fit(cells[c], width[c]);
      std::string pad(width[c] - cell.size(), ' ');
      if (c) s += "  ";
      s += aligns_[c] == Align::left ? cell + pad : pad + cell;
    }
    while (!s.empty() && s.back() == ' ') s.pop_back();
    out << s << '\n';
  };
  line(headers_);
  std::vector<std::string> rule;
  for (std::size_t c = 0; c < n; ++c) rule.push_back(std::string(width[c], '-'));
  line(rule);
  for (const auto& r : rows_) line(r);
}

}  // namespace clastrace::analyze
