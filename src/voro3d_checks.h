// Argument checks shared by the extensions' functions: numpy arrays in, ValueError or TypeError
// naming the argument out.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace voro3d {
namespace py = pybind11;

using Points = py::array_t<double, py::array::c_style | py::array::forcecast>;
using Indices = py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>;

inline py::array_t<std::int64_t> to_array(const std::vector<std::int64_t>& values, py::ssize_t width) {
  py::array_t<std::int64_t> result({static_cast<py::ssize_t>(values.size()) / width, width});
  std::copy(values.begin(), values.end(), result.mutable_data());
  return result;
}

inline std::string shape_of(const py::array& array) {
  std::string text = "(";
  for (py::ssize_t i = 0; i < array.ndim(); ++i) {
    text += (i ? ", " : "") + std::to_string(array.shape(i));
  }
  return text + (array.ndim() == 1 ? ",)" : ")");
}

// `value` as a numpy array of one of `kinds` (numpy dtype kind characters), else TypeError.
inline py::array as_array(const py::handle& value, const char* name, const std::string& kinds, const char* expected) {
  py::array array = py::array::ensure(value);
  if (!array) {
    throw py::type_error(std::string(name) + " must be an array, got " + std::string(py::str(py::type::handle_of(value).attr("__name__"))));
  }
  if (kinds.find(array.dtype().kind()) == std::string::npos) {
    throw py::type_error(std::string(name) + " must be " + expected + ", got dtype " + std::string(py::str(array.dtype())));
  }
  return array;
}

// A 2-d array of `columns` columns (at least -columns where negative), else ValueError citing `expected`.
inline void check_columns(const py::array& array, const char* name, const std::string& expected, py::ssize_t columns) {
  if (array.ndim() != 2 || (columns > 0 && array.shape(1) != columns) || (columns < 0 && array.shape(1) < -columns)) {
    throw py::value_error(std::string(name) + " must have shape " + expected + ", got " + shape_of(array));
  }
}

inline void check_shape(const py::array& array, const char* name, py::ssize_t width, const char* letter) {
  check_columns(array, name, "(" + std::string(letter) + ", " + std::to_string(width) + ")", width);
}

// Finite float64 (n, 3) coordinates with at least `min_rows` rows.
inline Points check_points(const py::handle& value, const char* name, py::ssize_t min_rows) {
  py::array array = as_array(value, name, "fiu", "a real-valued array");
  check_shape(array, name, 3, "n");
  if (array.shape(0) < min_rows) {
    throw py::value_error(std::string(name) + " must hold at least " + std::to_string(min_rows) + " points, got " +
                          std::to_string(array.shape(0)));
  }
  Points points = Points::ensure(array);
  auto p = points.unchecked<2>();
  for (py::ssize_t i = 0; i < p.shape(0); ++i) {
    if (!(std::isfinite(p(i, 0)) && std::isfinite(p(i, 1)) && std::isfinite(p(i, 2)))) {
      throw py::value_error(std::string(name) + " holds NaN or inf at row " + std::to_string(i));
    }
  }
  return points;
}

// An (m, width) integer array whose every entry indexes one of `n` rows of `target`.
inline Indices check_indices(const py::handle& value, const char* name, py::ssize_t width, const char* letter,
                             py::ssize_t n, const char* target) {
  py::array array = as_array(value, name, "iu", "an integer array of indices");
  check_shape(array, name, width, letter);
  Indices indices = Indices::ensure(array);
  auto t = indices.unchecked<2>();
  for (py::ssize_t i = 0; i < t.shape(0); ++i) {
    for (py::ssize_t j = 0; j < width; ++j) {
      if (t(i, j) < 0 || t(i, j) >= n) {
        throw py::value_error(std::string(name) + " holds index " + std::to_string(t(i, j)) + " at row " +
                              std::to_string(i) + ", outside [0, " + std::to_string(n) + ") for the " +
                              std::to_string(n) + " rows of " + target);
      }
    }
  }
  return indices;
}

using Mask = py::array_t<bool, py::array::c_style | py::array::forcecast>;

// A boolean (n,) array.
inline Mask check_mask(const py::handle& value, const char* name, py::ssize_t n) {
  py::array array = as_array(value, name, "b", "a boolean array");
  if (array.ndim() != 1 || array.shape(0) != n) {
    throw py::value_error(std::string(name) + " must have shape (" + std::to_string(n) + ",), got " + shape_of(array));
  }
  return Mask::ensure(array);
}
}  // namespace voro3d
