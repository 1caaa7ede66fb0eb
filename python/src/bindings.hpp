#pragma once
// What the Python module's files share (module.cpp binds the library, vec_env.cpp the
// environment): numpy's array type as the bindings take it, and the environment's pieces that
// other bindings reach.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "skyloop/env/spec.hpp"

namespace skyloop::pybind {

/// A C-contiguous numpy array of T (other dtypes and layouts converted on the way in).
template <class T>
using Array = pybind11::array_t<T, pybind11::array::c_style | pybind11::array::forcecast>;

/// The environment's spec (skyloop/env/spec.hpp) as plain Python values.
pybind11::dict env_spec_dict(const EnvSpec& e);

/// skyloop.VecEnv: the batch-first environment (vec_env.cpp).
void bind_vec_env(pybind11::module_& m);

}  // namespace skyloop::pybind
