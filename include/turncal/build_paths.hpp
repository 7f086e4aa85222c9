// Where this build tree's files are, for the programs' defaults and the
// tests. Defined in sources that CMake generates in the build tree
// (cmake/data_dir.cpp.in for the programs, cmake/build_paths.cpp.in for
// the tests alone), so that no other file's compilation depends on where
// the tree is: a compiler cache serves every clone of it.
#pragma once

namespace turncal::build {

/// The source tree.
extern const char* const source_dir;
/// Where turncald, turncalctl and turncal-sim look for turncal.toml when
/// not given --config (TURNCAL_DATA_DIR: the source tree's config/ in a
/// build tree, the installed one in a package).
extern const char* const data_dir;
/// The build tree.
extern const char* const binary_dir;
/// The programs as built.
extern const char* const sim_bin;
extern const char* const daemon_bin;
extern const char* const ctl_bin;

}  // namespace turncal::build
