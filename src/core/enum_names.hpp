// Names of an enumeration's values, for toString() / parse...() pairs: one table per enum, the
// first entry of a value its name, later ones accepted aliases. Private to the core libraries.
#pragma once

#include <cstddef>
#include <string>

namespace endo_stereo {
namespace detail {

template <typename E>
struct EnumName {
  E value;
  const char* name;
};

/// The name of @p value (its first entry), or @p fallback when the table has none.
template <typename E, size_t N>
std::string nameOf(const EnumName<E> (&table)[N], E value, const char* fallback) {
  for (const EnumName<E>& e : table) {
    if (e.value == value) return e.name;
  }
  return fallback;
}

/// The value named @p text (a name or an alias); false when none is.
template <typename E, size_t N>
bool valueOf(const EnumName<E> (&table)[N], const std::string& text, E* value) {
  for (const EnumName<E>& e : table) {
    if (text == e.name) {
      *value = e.value;
      return true;
    }
  }
  return false;
}

}  // namespace detail
}  // namespace endo_stereo
