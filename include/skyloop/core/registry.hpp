#pragma once
// One registry template for every open set of named things a user extends: beamformers,
// planners, learners, mobility (dynamics), path-loss and fading models, experiment kinds. Each is a
// Registry<Entry> of rows (name, one line of help, entry: a factory or a descriptor), built once
// where its subsystem lives; the configuration's allowed values, the CLI's lists and help, the
// docs' reference and every lookup read it. Closed sets of values are enums instead
// (skyloop/core/choices.hpp).
//
//   Registry<Factory> r("planner '{}'");   // how a name is quoted in errors
//   r.add("mine", "my planner", make_mine);
//   r.at("mine")(args);                     // InputError "planner 'x' is unknown: allowed ..." else
#include <algorithm>
#include <string>
#include <utility>
#include <vector>

#include "skyloop/core/error.hpp"

namespace skyloop {

template <class Entry>
class Registry {
 public:
  struct Row {
    std::string name;
    std::string help;  // one line
    Entry entry;
  };
  enum class Order { Registration, Name };

  /// `quoted` is how an unknown name is written in errors, "{}" standing for the name:
  /// "planner '{}'" or, for a configuration key, "trajectory.mobility = \"{}\"". Names are listed
  /// in the order of their first registration, or sorted (Order::Name).
  explicit Registry(std::string quoted, std::vector<Row> rows = {}, Order order = Order::Registration)
      : quoted_(std::move(quoted)), order_(order) {
    for (auto& r : rows) add(std::move(r.name), std::move(r.help), std::move(r.entry));
  }

  /// Adds a row, or replaces the row of the same name in its place.
  void add(std::string name, std::string help, Entry entry) {
    for (auto& r : rows_)
      if (r.name == name) {
        r.help = std::move(help), r.entry = std::move(entry);
        return;
      }
    rows_.push_back(Row{std::move(name), std::move(help), std::move(entry)});
    if (order_ == Order::Name)
      std::stable_sort(rows_.begin(), rows_.end(), [](const Row& a, const Row& b) { return a.name < b.name; });
  }

  /// The row named so, or nullptr.
  const Row* find(const std::string& name) const {
    for (const auto& r : rows_)
      if (r.name == name) return &r;
    return nullptr;
  }
  bool contains(const std::string& name) const { return find(name) != nullptr; }

  /// The entry named so; InputError "<quoted> is unknown: allowed a, b, c" otherwise.
  const Entry& at(const std::string& name) const {
    if (const Row* r = find(name)) return r->entry;
    throw InputError(unknown(name));
  }

  /// The error line for a name that is not here.
  std::string unknown(const std::string& name) const {
    std::string q = quoted_;
    const auto at = q.find("{}");
    if (at != std::string::npos) q.replace(at, 2, name);
    return q + " is unknown: allowed " + names_text();
  }

  const std::vector<Row>& rows() const { return rows_; }
  std::vector<std::string> names() const {
    std::vector<std::string> out;
    for (const auto& r : rows_) out.push_back(r.name);
    return out;
  }
  /// "a, b, c".
  std::string names_text() const {
    std::string out;
    for (const auto& r : rows_) out += (out.empty() ? "" : ", ") + r.name;
    return out;
  }
  /// "a: help; b: help", for a field's or an option's help line.
  std::string help_text() const {
    std::string out;
    for (const auto& r : rows_) out += (out.empty() ? "" : "; ") + r.name + ": " + r.help;
    return out;
  }
  /// (name, help) pairs, in the registry's order.
  std::vector<std::pair<std::string, std::string>> list() const {
    std::vector<std::pair<std::string, std::string>> out;
    for (const auto& r : rows_) out.emplace_back(r.name, r.help);
    return out;
  }

 private:
  std::string quoted_;
  Order order_;
  std::vector<Row> rows_;
};

}  // namespace skyloop
