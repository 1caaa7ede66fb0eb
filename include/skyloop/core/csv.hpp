#pragma once
// Reading skyloop's own CSV output back: columns are found by name, never by position, so a
// column added to a writer cannot shift what a reader takes. Fields hold no commas or quotes
// (skyloop writes numbers, names and specs), so a line splits on every comma.
#include <cstddef>
#include <string>
#include <vector>

namespace skyloop {

class CsvTable {
 public:
  /// Parses `text` (a header line, then rows). `source` names it in errors.
  static CsvTable parse(const std::string& text, const std::string& source);

  const std::vector<std::string>& columns() const { return columns_; }
  std::size_t size() const { return rows_.size(); }
  bool has(const std::string& column) const;
  /// Field of `row` in `column`; throws std::runtime_error naming the source and the columns it has.
  const std::string& at(std::size_t row, const std::string& column) const;
  double number(std::size_t row, const std::string& column) const;

 private:
  std::string source_;
  std::vector<std::string> columns_;
  std::vector<std::vector<std::string>> rows_;
  std::size_t index(const std::string& column) const;
};

/// Splits one CSV line on commas.
std::vector<std::string> split_csv_line(const std::string& line);
/// The non-empty lines of `text`.
std::vector<std::string> text_lines(const std::string& text);
/// The first line of a CSV text, and everything after it.
std::string csv_header(const std::string& csv);
std::string csv_body(const std::string& csv);
/// Every data line of `csv` with `prefix` (which ends with a comma) in front.
std::string csv_prefixed(const std::string& csv, const std::string& prefix);

}  // namespace skyloop
