#include "skyloop/core/csv.hpp"

#include <sstream>
#include <stdexcept>

namespace skyloop {

std::vector<std::string> split_csv_line(const std::string& line) {
  std::vector<std::string> f;
  std::string cur;
  for (char ch : line) {
    if (ch == ',') f.push_back(cur), cur.clear();
    else if (ch != '\r') cur += ch;
  }
  f.push_back(cur);
  return f;
}

std::vector<std::string> text_lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) out.push_back(line);
  return out;
}

std::string csv_header(const std::string& csv) { return csv.substr(0, csv.find('\n')); }

std::string csv_body(const std::string& csv) {
  const auto nl = csv.find('\n');
  return nl == std::string::npos ? std::string() : csv.substr(nl + 1);
}

std::string csv_prefixed(const std::string& csv, const std::string& prefix) {
  std::string out;
  for (const auto& line : text_lines(csv_body(csv))) out += prefix + line + "\n";
  return out;
}

CsvTable CsvTable::parse(const std::string& text, const std::string& source) {
  CsvTable t;
  t.source_ = source;
  const auto lines = text_lines(text);
  if (lines.empty()) throw std::runtime_error(source + ": empty CSV (no header line)");
  t.columns_ = split_csv_line(lines.front());
  for (std::size_t i = 1; i < lines.size(); ++i) {
    auto f = split_csv_line(lines[i]);
    if (f.size() != t.columns_.size())
      throw std::runtime_error(source + ": line " + std::to_string(i + 1) + " has " + std::to_string(f.size()) +
                               " fields, the header " + std::to_string(t.columns_.size()));
    t.rows_.push_back(std::move(f));
  }
  return t;
}

bool CsvTable::has(const std::string& column) const {
  for (const auto& c : columns_)
    if (c == column) return true;
  return false;
}

std::size_t CsvTable::index(const std::string& column) const {
  for (std::size_t i = 0; i < columns_.size(); ++i)
    if (columns_[i] == column) return i;
  std::string all;
  for (const auto& c : columns_) all += (all.empty() ? "" : ", ") + c;
  throw std::runtime_error(source_ + ": no column '" + column + "' (columns: " + all + ")");
}

const std::string& CsvTable::at(std::size_t row, const std::string& column) const { return rows_.at(row)[index(column)]; }

double CsvTable::number(std::size_t row, const std::string& column) const {
  const std::string& s = at(row, column);
  std::size_t used = 0;
  double v = 0;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (s.empty() || used != s.size())
    throw std::runtime_error(source_ + ": row " + std::to_string(row + 1) + ", column '" + column + "' = '" + s + "' is not a number");
  return v;
}

}  // namespace skyloop
