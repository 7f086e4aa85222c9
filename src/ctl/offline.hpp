// turncalctl's commands that need no daemon (replay, plan, dbc, decode). Internal to
// turncalctl.
#pragma once

namespace turncal::ctl {

/// Exit codes of turncalctl.
inline constexpr int kOk = 0, kRefused = 1, kUsage = 2, kUnreachable = 3;

/// Prints the usage with `why` and returns kUsage.
int usage(const char* why);

/// `turncalctl replay LOG ...`; argv[i] is the first argument after "replay".
int replay(int argc, char** argv, int i, bool as_json);

/// `turncalctl plan ...`: the covariance analysis of a planned experiment.
int plan(int argc, char** argv, int i, bool as_json);
/// `turncalctl check`: a whole stand configuration (its DBC, the roles
/// against the INS layout and the table protocol, the plans against the
/// stand's limits and command ranges), without starting a run.
int check(int argc, char** argv, int i, bool as_json);

/// `turncalctl dbc FILE.dbc`: what a DBC file holds, as read, and its
/// warnings; kRefused with the error (file:line) when it cannot be used.
int dbc(int argc, char** argv, int i, bool as_json);

/// `turncalctl decode FILE.dbc LOG [--json]`: a candump log decoded by a
/// DBC file, a line per frame; malformed lines are counted and skipped.
int decode(int argc, char** argv, int i, bool as_json);

}  // namespace turncal::ctl
