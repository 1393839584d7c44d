//! The documentation's commands, run: every shell block of README.md and
//! docs/*.md marked `<!-- doc-test: run -->` is run with bash, in order, in
//! one shell, against a stack this test starts (`vlnav up`'s stack, with its
//! credentials in `./.vlnav/security` as a user would have them); blocks
//! marked `<!-- doc-test: check -->` (a cluster, a robot, minutes of work)
//! are checked with `bash -n`, as are blocks marked `<!-- doc-test: robot -->`
//! (README.md's "Connecting a real robot", which `tests/tests/real_robot.rs`
//! runs on two "computers" with a ROS 2 robot), and every block for flags: a `--flag` given
//! to one of the deployment's binaries (by name, by path or through
//! `cargo run -p … --`) must be in that command's `--help`.
//!
//! In a run block, lines starting `$ ` are commands (continued by a trailing
//! `\`), the lines after one are the output it shows: each shown line must
//! appear, in order, in what the command printed, with numbers and ids
//! taken as wildcards; `...` stands for lines left out. In a block without
//! `$ ` lines each line is a command that shows nothing. Every command must
//! exit 0.
//!
//! Also here: `docs/cli.md` and the generated part of
//! `docs/configuration.md` must be what the binaries' `--help` says.
//! Regenerate both with
//! `VLNAV_BLESS=1 cargo test -p vlnav-e2e --test docs_commands reference`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use vlnav_e2e::procs::{DEPLOYED, binaries};
use vlnav_e2e::{TestStack, reader_shell, repo_root};

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Run,
    Check,
}

#[derive(Debug)]
struct Block {
    file: String,
    line: usize,
    mode: Mode,
    text: String,
}

/// The marked shell blocks of README.md and docs/*.md, in file order.
fn marked_blocks() -> Vec<Block> {
    let root = repo_root();
    let mut files = vec![root.join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    let mut blocks = Vec::new();
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        let name = path.strip_prefix(&root).unwrap().display().to_string();
        let lines: Vec<&str> = text.lines().collect();
        let mut i = 0;
        while i < lines.len() {
            let mode = match lines[i].trim() {
                "<!-- doc-test: run -->" => Some(Mode::Run),
                "<!-- doc-test: check -->" | "<!-- doc-test: robot -->" => Some(Mode::Check),
                _ => None,
            };
            i += 1;
            let Some(mode) = mode else { continue };
            assert!(
                i < lines.len() && lines[i].starts_with("```"),
                "{name}:{i}: a doc-test marker must stand right before a fenced block"
            );
            let start = i + 1;
            let end = (start..lines.len()).find(|&j| lines[j].starts_with("```")).expect("the fence closes");
            blocks.push(Block { file: name.clone(), line: start, mode, text: lines[start..end].join("\n") });
            i = end + 1;
        }
    }
    blocks
}

/// A run block's commands, each with the output it shows. In a block
/// without `$ ` lines every line (with its `\` continuations) is a command
/// that shows no output; comments and blank lines are skipped.
fn commands(block: &Block) -> Vec<(String, Vec<String>)> {
    let prompted = block.text.lines().any(|l| l.starts_with("$ "));
    let mut out: Vec<(String, Vec<String>)> = Vec::new();
    let mut continued = false;
    for line in block.text.lines() {
        if continued {
            let last = out.last_mut().unwrap();
            last.0.push('\n');
            last.0.push_str(line);
            continued = line.ends_with('\\');
            continue;
        }
        let command = if prompted {
            line.strip_prefix("$ ")
        } else {
            Some(line).filter(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        };
        if let Some(cmd) = command {
            out.push((cmd.to_string(), Vec::new()));
            continued = cmd.ends_with('\\');
        } else if prompted && let Some(last) = out.last_mut() {
            last.1.push(line.to_string());
        }
    }
    out
}

/// Numbers and ids become wildcards; whitespace at the ends does not count.
fn shape(line: &str) -> String {
    let mut out = String::new();
    let mut word = String::new();
    let flush = |word: &mut String, out: &mut String| {
        let is_id = word.len() >= 12 && word.chars().all(|c| c.is_ascii_hexdigit());
        let is_number = !word.is_empty() && word.chars().all(|c| c.is_ascii_digit() || c == '.');
        out.push_str(if is_id || is_number { "#" } else { word.as_str() });
        word.clear();
    };
    for c in line.trim().chars() {
        if c.is_ascii_alphanumeric() || c == '.' {
            word.push(c);
        } else {
            flush(&mut word, &mut out);
            out.push(c);
        }
    }
    flush(&mut word, &mut out);
    out.replace("-#", "#")
}

/// Where the shown lines do not appear in order in `actual`, the first that does not.
fn missing_line(shown: &[String], actual: &str) -> Option<String> {
    let actual: Vec<String> = actual.lines().map(shape).collect();
    let mut at = 0;
    for want in shown.iter().filter(|l| l.trim() != "..." && !l.trim().is_empty()) {
        let want_shape = shape(want);
        match actual[at..].iter().position(|a| *a == want_shape) {
            Some(k) => at += k + 1,
            None => return Some(want.clone()),
        }
    }
    None
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_documented_commands_run_against_a_stack() {
    let blocks: Vec<Block> = marked_blocks().into_iter().filter(|b| b.mode == Mode::Run).collect();
    assert!(!blocks.is_empty(), "no runnable block found");
    let bin = binaries().expect("the binaries build");
    let home = tempfile::tempdir().unwrap();
    let dir = home.path().to_path_buf();
    std::os::unix::fs::symlink(repo_root().join("models"), dir.join("models")).unwrap();
    let data = dir.join(".vlnav");
    let t = TestStack::start(|a| a.data_dir = data.clone()).await;
    let p = t.stack.ports;
    let addr = t.addr();
    let mut ports = vec![("127.0.0.1:50051".to_string(), addr.clone())];
    for (default, port) in [
        (50052, p.ingress),
        (50053, p.planner),
        (50054, p.detector),
        (50055, p.reid),
        (50056, p.segmenter),
        (50057, p.subgoal),
        (50058, p.local_planner),
    ] {
        ports.push((format!("127.0.0.1:{default}"), format!("127.0.0.1:{port}")));
    }

    let mut script = String::from("exec 2>&1\nset -o pipefail\n");
    let mut index = Vec::new();
    for block in &blocks {
        for (cmd, shown) in commands(block) {
            let mut cmd = cmd;
            for (from, to) in &ports {
                cmd = cmd.replace(from.as_str(), to);
            }
            let n = index.len();
            script
                .push_str(&format!("printf '\\n@@begin {n}\\n'\n{cmd}\n__rc=$?\nprintf '\\n@@end {n} %d\\n' $__rc\n"));
            index.push((block, cmd, shown));
        }
    }
    let gateway = t.uri();
    let run = tokio::task::spawn_blocking(move || {
        reader_shell(&script, &dir, &bin).env("VLNAV_GATEWAY", gateway).output().expect("bash runs")
    });
    let out = tokio::time::timeout(Duration::from_secs(300), run)
        .await
        .expect("the documented commands finish within 5 minutes")
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();

    let mut failures = Vec::new();
    for (n, (block, cmd, shown)) in index.iter().enumerate() {
        let begin = format!("@@begin {n}\n");
        let Some(b) = text.find(&begin) else {
            failures.push(format!("{}:{}: `{cmd}` did not run", block.file, block.line));
            continue;
        };
        let rest = &text[b + begin.len()..];
        let end_tag = format!("\n@@end {n} ");
        let e = rest.find(&end_tag).unwrap_or(rest.len());
        let printed = &rest[..e];
        let rc: i32 =
            rest[e..].trim_start_matches(&end_tag).lines().next().and_then(|s| s.trim().parse().ok()).unwrap_or(-1);
        if rc != 0 {
            failures.push(format!("{}:{}: `{cmd}` exited {rc}:\n{printed}", block.file, block.line));
        } else if let Some(line) = missing_line(shown, printed) {
            failures.push(format!(
                "{}:{}: `{cmd}` did not print a line shaped like\n  {line}\nit printed:\n{printed}",
                block.file, block.line
            ));
        }
    }
    t.stack.shutdown().await.unwrap();
    assert!(failures.is_empty(), "documented commands that do not work as shown:\n\n{}", failures.join("\n\n"));
}

/// `--help` of `bin` with the given subcommand path, in a clean environment
/// (so `[env: …]` shows no value of this machine), this checkout's path
/// written as `.`.
fn help(bin: &Path, sub: &[&str]) -> String {
    let out = Command::new(bin)
        .args(sub)
        .arg("--help")
        .env_clear()
        .env("PATH", std::env::var("PATH").unwrap_or_default())
        .env("COLUMNS", "100")
        .output()
        .expect("the binary runs");
    assert!(out.status.success(), "{} {sub:?} --help failed: {}", bin.display(), String::from_utf8_lossy(&out.stderr));
    let root = repo_root().display().to_string();
    String::from_utf8_lossy(&out.stdout).trim_end().replace(&root, ".")
}

/// The subcommands a help text lists.
fn subcommands(help: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut inside = false;
    for line in help.lines() {
        if line.starts_with("Commands:") {
            inside = true;
        } else if inside && line.starts_with("  ") && !line.starts_with("   ") {
            let name = line.split_whitespace().next().unwrap_or("");
            if name != "help" {
                out.push(name.to_string());
            }
        } else if inside && !line.starts_with(' ') {
            inside = false;
        }
    }
    out
}

/// Every command path of every binary with its help: ("vlnav up", text).
fn every_help() -> BTreeMap<String, String> {
    let dir = binaries().expect("the binaries build");
    let mut out = BTreeMap::new();
    let mut todo: Vec<(String, Vec<String>)> = DEPLOYED.iter().map(|(_, b)| (b.to_string(), Vec::new())).collect();
    while let Some((bin, sub)) = todo.pop() {
        let args: Vec<&str> = sub.iter().map(String::as_str).collect();
        let text = help(&dir.join(&bin), &args);
        for s in subcommands(&text) {
            let mut next = sub.clone();
            next.push(s);
            todo.push((bin.clone(), next));
        }
        let name = std::iter::once(bin.as_str()).chain(args.iter().copied()).collect::<Vec<_>>().join(" ");
        out.insert(name, text);
    }
    out
}

/// One option of a help text: its flag, env variable and default.
struct Opt {
    flag: String,
    env: Option<String>,
    default: Option<String>,
}

fn options(help: &str) -> Vec<Opt> {
    let mut blocks: Vec<String> = Vec::new();
    for line in help.lines() {
        let t = line.trim_start();
        let indent = line.len() - t.len();
        if (t.starts_with("--") || (t.starts_with('-') && t.chars().nth(1).is_some_and(|c| c.is_alphanumeric())))
            && indent <= 6
        {
            blocks.push(t.to_string());
        } else if let Some(b) = blocks.last_mut()
            && indent > 6
        {
            b.push(' ');
            b.push_str(t);
        } else if !line.is_empty() && indent <= 2 {
            blocks.push(String::new());
        }
    }
    let between = |s: &str, open: &str| -> Option<String> {
        let i = s.find(open)? + open.len();
        let j = s[i..].find(']')? + i;
        Some(s[i..j].trim_end_matches('=').to_string())
    };
    blocks
        .into_iter()
        .filter(|b| b.starts_with('-'))
        .filter_map(|b| {
            let flag = b.split(|c: char| c.is_whitespace() || c == ',').find(|w| w.starts_with("--"))?.to_string();
            Some(Opt { flag, env: between(&b, "[env: "), default: between(&b, "[default: ") })
        })
        .collect()
}

fn cli_page(helps: &BTreeMap<String, String>) -> String {
    let mut page = String::from(
        "# Command-line reference\n\n\
         Generated from the `--help` of every binary; do not edit by hand.\n\
         Regenerate: `VLNAV_BLESS=1 cargo test -p vlnav-e2e --test docs_commands reference`\n\
         (`tests/tests/docs_commands.rs` fails when this page and the binaries disagree).\n\
         Every flag's environment variable and default are listed with it;\n\
         [configuration.md](configuration.md) lists the variables.\n\n",
    );
    for name in helps.keys() {
        let anchor: String = name.replace(' ', "-");
        page.push_str(&format!("- [`{name}`](#{anchor})\n"));
    }
    for (name, text) in helps {
        page.push_str(&format!("\n## {name}\n\n```text\n{text}\n```\n"));
    }
    page
}

/// The variables read without a flag, with the files that read them: in
/// Rust, a `VLNAV_…` literal passed to `env::var`, `env::var_os` or
/// `env_u64`; in the shell scripts and the Makefile, a `${VLNAV_…}` expansion.
fn direct_variables() -> BTreeMap<String, Vec<String>> {
    let root = repo_root();
    let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut stack = vec![root.clone()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            if p.is_dir() {
                let skipped = ["target", "models", "node_modules", "docs"].contains(&name.as_str());
                if !skipped && (!name.starts_with('.') || name == ".ci") {
                    stack.push(p);
                }
                continue;
            }
            let openers: &[&str] = if name.ends_with(".rs") {
                &["var(\"VLNAV_", "var_os(\"VLNAV_", "env_u64(\"VLNAV_"]
            } else if name.ends_with(".sh") || name == "Makefile" || dir.ends_with(".ci") {
                &["${VLNAV_"]
            } else {
                continue;
            };
            let text = std::fs::read_to_string(&p).unwrap_or_default();
            let file = p.strip_prefix(&root).unwrap().display().to_string();
            for line in text.lines().filter(|l| !l.trim_start().starts_with('#')) {
                for opener in openers {
                    for (i, _) in line.match_indices(opener) {
                        let start = i + opener.len() - "VLNAV_".len();
                        let var: String = line[start..]
                            .chars()
                            .take_while(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || *c == '_')
                            .collect();
                        let files = out.entry(var).or_default();
                        if !files.contains(&file) {
                            files.push(file.clone());
                        }
                    }
                }
            }
        }
    }
    for files in out.values_mut() {
        files.sort();
    }
    out
}

const GENERATED_BEGIN: &str = "<!-- generated: begin -->";
const GENERATED_END: &str = "<!-- generated: end -->";

/// Every variable a flag reads (flags, defaults and commands; one variable
/// can stand for differently named flags), then the ones read without one.
fn configuration_section(helps: &BTreeMap<String, String>) -> String {
    #[derive(Default)]
    struct Var {
        flags: Vec<String>,
        defaults: Vec<String>,
        commands: Vec<String>,
    }
    fn add(list: &mut Vec<String>, item: &str) {
        if !list.iter().any(|x| x == item) {
            list.push(item.to_string());
        }
    }
    let mut vars: BTreeMap<String, Var> = BTreeMap::new();
    for (name, text) in helps {
        for o in options(text) {
            if let Some(env) = o.env {
                let v = vars.entry(env).or_default();
                add(&mut v.flags, &o.flag);
                if let Some(d) = &o.default {
                    add(&mut v.defaults, d);
                }
                add(&mut v.commands, name);
            }
        }
    }
    let code = |items: &[String]| items.iter().map(|i| format!("`{i}`")).collect::<Vec<_>>().join(", ");
    let mut s = String::from("| variable | flag | default | commands |\n|---|---|---|---|\n");
    for (var, v) in &vars {
        let default = if v.defaults.is_empty() { "—".to_string() } else { code(&v.defaults) };
        s.push_str(&format!("| `{var}` | {} | {default} | {} |\n", code(&v.flags), code(&v.commands)));
    }
    s.push_str("\nRead without a flag:\n\n| variable | read in |\n|---|---|\n");
    for (var, files) in direct_variables() {
        if !vars.contains_key(&var) {
            s.push_str(&format!("| `{var}` | {} |\n", code(&files)));
        }
    }
    s
}

#[test]
fn reference_pages_match_the_binaries() {
    let helps = every_help();
    let root = repo_root();
    let bless = std::env::var_os("VLNAV_BLESS").is_some();
    let cli = cli_page(&helps);
    let cli_path = root.join("docs/cli.md");
    let conf_path = root.join("docs/configuration.md");
    let conf = std::fs::read_to_string(&conf_path).expect("docs/configuration.md");
    let (b, e) = (conf.find(GENERATED_BEGIN).expect("begin marker"), conf.find(GENERATED_END).expect("end marker"));
    let section = configuration_section(&helps);
    let new_conf = format!("{}{GENERATED_BEGIN}\n\n{section}\n{}", &conf[..b], &conf[e..]);
    if bless {
        std::fs::write(&cli_path, &cli).unwrap();
        std::fs::write(&conf_path, &new_conf).unwrap();
        return;
    }
    let regen = "regenerate: VLNAV_BLESS=1 cargo test -p vlnav-e2e --test docs_commands reference";
    assert!(
        std::fs::read_to_string(&cli_path).unwrap_or_default() == cli,
        "docs/cli.md is not what the binaries say; {regen}"
    );
    assert!(conf == new_conf, "docs/configuration.md's generated table is not what the binaries say; {regen}");
}

/// The simple commands of a logical command line, as words: split at `|`,
/// `;`, `&&`, `||`, `&`, at a `$(` and at a `(` that opens a word. Quoting is
/// ignored: what this looks for (a binary's name, `--flags`) does not hide in it.
fn simple_commands(line: &str) -> Vec<Vec<&str>> {
    let mut out: Vec<Vec<&str>> = vec![Vec::new()];
    for word in line.split_whitespace() {
        if ["|", ";", "&&", "||", "&"].contains(&word) {
            out.push(Vec::new());
            continue;
        }
        let opened = match word.rfind("$(") {
            Some(k) => Some(&word[k + 2..]),
            None => word.strip_prefix('('),
        };
        let word = match opened {
            Some(rest) => {
                out.push(Vec::new());
                rest
            }
            None => word,
        };
        if !word.is_empty() {
            out.last_mut().unwrap().push(word.trim_end_matches(';'));
        }
    }
    out.retain(|c| !c.is_empty());
    out
}

/// The binary a simple command runs, if it is one of ours, and the words
/// after it: `vlnav …`, `target/release/vlnav …`, `cargo run -p vlnav -- …`.
/// Variable assignments before the command are skipped.
fn our_command<'a>(words: &[&'a str]) -> Option<(&'static str, Vec<&'a str>)> {
    let words: Vec<&str> = words.iter().copied().skip_while(|w| w.contains('=') && !w.starts_with('-')).collect();
    let first = *words.first()?;
    let base = first.rsplit('/').next().unwrap_or(first);
    if let Some((_, bin)) = DEPLOYED.iter().find(|(_, b)| *b == base) {
        return Some((bin, words[1..].to_vec()));
    }
    if first == "cargo" && words.get(1) == Some(&"run") {
        let dashes = words.iter().position(|w| *w == "--")?;
        let value_of = |flag: &str| words[..dashes].windows(2).find(|p| p[0] == flag).map(|p| p[1]);
        let (_, bin) = match value_of("--bin") {
            Some(b) => DEPLOYED.iter().find(|(_, bin)| *bin == b)?,
            None => {
                let package = value_of("-p").or_else(|| value_of("--package"))?;
                DEPLOYED.iter().find(|(p, _)| *p == package)?
            }
        };
        return Some((bin, words[dashes + 1..].to_vec()));
    }
    None
}

/// Whether `help` lists the option `flag` (`--name`).
fn has_flag(help: &str, flag: &str) -> bool {
    flag == "--help" || flag == "--version" || options(help).iter().any(|o| o.flag == flag)
}

/// The flags a logical command line passes to our binaries, checked against
/// their help; returns what is wrong.
fn unknown_flags(line: &str, helps: &BTreeMap<String, String>) -> Vec<String> {
    let mut wrong = Vec::new();
    for words in simple_commands(line) {
        let Some((bin, args)) = our_command(&words) else { continue };
        let mut name = bin.to_string();
        let mut rest = args.as_slice();
        while let Some((word, after)) = rest.split_first() {
            let candidate = format!("{name} {word}");
            if !helps.contains_key(&candidate) {
                break;
            }
            name = candidate;
            rest = after;
        }
        let text = &helps[&name];
        for word in rest {
            if let Some(flag) = word.strip_prefix("--") {
                let flag: String = flag.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '-').collect();
                if !flag.is_empty() && !has_flag(text, &format!("--{flag}")) {
                    wrong.push(format!("`{name}` has no --{flag}"));
                }
            }
        }
    }
    wrong
}

#[test]
fn every_documented_command_parses_and_uses_flags_that_exist() {
    let helps = every_help();
    let mut failures = Vec::new();
    for block in marked_blocks() {
        let script = match block.mode {
            Mode::Check => block.text.clone(),
            Mode::Run => commands(&block).into_iter().map(|(c, _)| c).collect::<Vec<_>>().join("\n"),
        };
        let out = Command::new("bash").arg("-n").arg("-c").arg(&script).output().expect("bash runs");
        if !out.status.success() {
            failures.push(format!("{}:{}: bash -n: {}", block.file, block.line, String::from_utf8_lossy(&out.stderr)));
        }
        for line in script.replace("\\\n", " ").lines() {
            let code = line.split(" #").next().unwrap_or(line);
            for w in unknown_flags(code, &helps) {
                failures.push(format!("{}:{}: {w}", block.file, block.line));
            }
        }
    }
    assert!(failures.is_empty(), "documented commands that cannot work:\n{}", failures.join("\n"));
}

#[test]
fn a_block_splits_into_commands_and_the_output_they_show() {
    let block = |text: &str| Block { file: "x.md".into(), line: 1, mode: Mode::Run, text: text.into() };
    assert_eq!(
        commands(&block("$ a \\\n  b\nout 1\n...\n$ c\n")),
        [("a \\\n  b".to_string(), vec!["out 1".to_string(), "...".to_string()]), ("c".to_string(), vec![])]
    );
    assert_eq!(
        commands(&block("# a comment\nx=1\n\ny \\\n  z")),
        [("x=1".to_string(), vec![]), ("y \\\n  z".to_string(), vec![])]
    );
}

#[test]
fn shapes_take_numbers_and_ids_as_wildcards() {
    assert_eq!(
        shape(r#"  "missionId": "m-9673a8b48e4e41c5a71e3500beb3dd77","#),
        shape(r#""missionId": "m-0123456789abcdef0123456789abcdef","#)
    );
    assert_eq!(shape(r#""fDist": 2.5,"#), shape(r#""fDist": 1,"#));
    assert_ne!(shape("MISSION_STATE_SUCCEEDED"), shape("MISSION_STATE_FAILED"));
    let shown = vec!["a 1".to_string(), "...".to_string(), "c".to_string()];
    assert_eq!(missing_line(&shown, "a 22\nb\nc\n"), None);
    assert_eq!(missing_line(&shown, "c\na 22\n"), Some("c".to_string()));
}

#[test]
fn flags_are_checked_where_one_of_our_binaries_runs() {
    let helps: BTreeMap<String, String> = [
        (
            "vlnav",
            "Usage: vlnav <COMMAND>\n\nCommands:\n  up    Run\n  help  Print\n\nOptions:\n  -h, --help  Print help",
        ),
        (
            "vlnav up",
            "Usage: vlnav up [OPTIONS]\n\nOptions:\n      --perception <P>\n          Which\n  -h, --help  Print help",
        ),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    let wrong = |line: &str| unknown_flags(line, &helps);
    let no_such = vec!["`vlnav up` has no --nope".to_string()];
    assert!(wrong("vlnav up --perception oracle --help").is_empty());
    assert!(wrong("kubectl -n vlnav rollout status deploy --timeout=10m").is_empty());
    assert!(wrong("echo vlnav up --nope").is_empty());
    assert_eq!(wrong("vlnav up --nope"), no_such);
    assert_eq!(wrong("X=1 target/release/vlnav up --nope=2"), no_such);
    assert_eq!(wrong("ID=$(vlnav up --nope) && echo"), no_such);
    assert_eq!(wrong("cargo run --release -p vlnav -- up --nope"), no_such);
    assert_eq!(wrong("vlnav --nope"), vec!["`vlnav` has no --nope".to_string()]);
}
