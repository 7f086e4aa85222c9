# Writes the body of turncal.toml(5) from commented configuration files:
# every comment block above a key is that key's description, a key's comment
# on its own line too, and a [section]'s comment block the section's. The
# files given are read whole, except where a variable `only` names one
# section: from such a file only that section (and the comment above it).
# The configuration's comments are the one source, so the manual page cannot
# drift from the file an administrator edits.
function esc(s) {
  gsub(/\\/, "\\e", s)
  gsub(/-/, "\\-", s)
  return s
}
function line_out(s) {
  s = esc(s)
  if (s ~ /^[.']/) s = "\\&" s
  print s
}
function flush_text(   i) {
  for (i = 1; i <= ntext; i++) line_out(text[i])
  ntext = 0
}
function flush_example(   i) {
  if (nex == 0) return
  print ".PP\n.nf\n.RS 4"
  for (i = 1; i <= nex; i++) line_out(ex[i])
  print ".RE\n.fi"
  nex = 0
}
function flush_keys(   i) {
  if (nkeys == 0) return
  for (i = 1; i <= nkeys; i++) {
    print (i == 1 ? ".TP" : ".TQ")
    print "\\fB" esc(keys[i]) "\\fR = " esc(vals[i])
  }
  if (ntext == 0 && ninline > 0) {
    for (i = 1; i <= ninline; i++) line_out(inl[i])
  } else {
    flush_text()
    if (ninline > 0) { print ".br"; for (i = 1; i <= ninline; i++) line_out(inl[i]) }
  }
  nkeys = 0; ninline = 0
}
function flush_all() {
  flush_keys()
  flush_example()
  if (ntext > 0) { print ".PP"; flush_text() }
}
FNR == 1 { if (skipping) ntext = 0; flush_all(); head = 1; skipping = (only != "" && FILENAME == onlyfile) }
# the file's first comment block is about the file, not a key
head && /^#/ { if (FILENAME != onlyfile) { sub(/^# ?/, ""); intro[++nintro] = $0 }; next }
head && /^$/ { head = 0; if (nintro > 0 && !intro_done) { print ".SH DESCRIPTION"; for (i = 1; i <= nintro; i++) line_out(intro[i]); print ".PP\nEvery key is described below, section by section, with its default."; intro_done = 1 }; nintro = 0; next }
{ head = 0 }
/^\[/ {
  sec = $0; sub(/[ \t]*#.*$/, "", sec)
  if (only != "" && FILENAME == onlyfile) {
    skipping = (sec != "[" only "]")
    if (skipping) { ntext = 0; next }
  }
  if (skipping) next
  flush_keys(); flush_example()
  print ".SS " esc(sec)
  if (ntext > 0) { print ".PP"; flush_text() }
  # a section taken from an example stand shows that stand's values
  if (FILENAME == onlyfile) {
    print ".PP"
    line_out("The values shown are the example CiA 402 stand's (stands/cia402/turncal.toml), not always the defaults: each key's description gives its default.")
  }
  next
}
skipping { if (/^#/) { sub(/^# ?/, ""); text[++ntext] = $0 } else if (/^$/) ntext = 0; next }
/^[ \t]+#/ { sub(/^[ \t]+# ?/, ""); inl[++ninline] = $0; next }
sec == "[tolerances]" && /^# [a-z_0-9]+ = \{/ { flush_keys(); sub(/^# /, ""); ex[++nex] = $0; next }
/^#/ {
  if (nkeys > 0) flush_keys()
  flush_example()
  sub(/^# ?/, ""); text[++ntext] = $0; next
}
/^[a-z_0-9]+[ \t]*=/ {
  # keys one after another share the comment above them; a key with a
  # comment of its own on its line stands alone
  if (nkeys > 0 && ninline > 0) flush_keys()
  k = $0; sub(/[ \t]*=.*/, "", k)
  v = $0; sub(/^[^=]*=[ \t]*/, "", v)
  c = ""
  if (match(v, /[ \t]+# /)) { c = substr(v, RSTART + RLENGTH); v = substr(v, 1, RSTART - 1) }
  keys[++nkeys] = k; vals[nkeys] = v
  if (c != "") inl[++ninline] = c
  next
}
/^$/ { flush_all(); next }
END { if (skipping) ntext = 0; flush_all() }
