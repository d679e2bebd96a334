//! Asking: a component's answers one by one, each checked before the next.

use std::path::{Path, PathBuf};

use super::check::{check_name, parse_port, property_view};
use super::{ComponentSpec, Mode, Refusal, refuse};

/// Asks for a component's answers one by one on `input` (a terminal, or a script's lines), checking each
/// before the next and asking again with the reason when it is refused. Lists are comma-separated; an
/// empty line takes the default shown in brackets.
pub fn ask(
    input: &mut impl std::io::BufRead,
    output: &mut impl std::io::Write,
) -> std::io::Result<(ComponentSpec, PathBuf)> {
    let mut question = |text: &str, default: &str, check: &dyn Fn(&str) -> Result<(), Refusal>| {
        loop {
            if default.is_empty() {
                write!(output, "{text}: ")?;
            } else {
                write!(output, "{text} [{default}]: ")?;
            }
            output.flush()?;
            let mut line = String::new();
            if input.read_line(&mut line)? == 0 {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "no more answers",
                ));
            }
            let answer = match line.trim() {
                "" => default.to_owned(),
                given => given.to_owned(),
            };
            match check(&answer) {
                Ok(()) => return Ok(answer),
                Err(why) => writeln!(output, "  {why}")?,
            }
        }
    };
    let list = |text: &str| -> Vec<String> {
        text.split(',')
            .map(str::trim)
            .filter(|t| !t.is_empty())
            .map(str::to_owned)
            .collect()
    };
    let name = question("Component name", "", &|a| check_name("component", a))?;
    let pack = question("Pack folder", ".", &|a| {
        let folder = Path::new(a);
        if folder.join("src/lib.rs").is_file() || folder.join("src/pack.cpp").is_file() {
            Ok(())
        } else {
            Err(refuse(
                format!("{a} is not a pack made by `kairos new pack`"),
                None,
            ))
        }
    })?;
    let mode = question("Mode (threaded, reactive, periodic)", "threaded", &|a| {
        ["threaded", "reactive", "periodic"]
            .contains(&a)
            .then_some(())
            .ok_or_else(|| refuse("one of threaded, reactive, periodic", None))
    })?;
    let inputs = question("Inputs, name:type, comma-separated", "", &|a| {
        list(a)
            .iter()
            .try_for_each(|i| parse_port("input", i, true).map(|_| ()))
    })?;
    let outputs = question("Outputs, name:type", "", &|a| {
        list(a)
            .iter()
            .try_for_each(|o| parse_port("output", o, false).map(|_| ()))
    })?;
    let properties = question("Properties, name:type=default", "", &|a| {
        list(a).iter().try_for_each(|p| property_view(p).map(|_| ()))
    })?;
    let actions = question("Actions, names", "", &|a| {
        list(a).iter().try_for_each(|n| check_name("action", n))
    })?;
    let spec = ComponentSpec {
        name,
        inputs: list(&inputs),
        outputs: list(&outputs),
        properties: list(&properties),
        actions: list(&actions),
        mode: match mode.as_str() {
            "reactive" => Mode::Reactive,
            "periodic" => Mode::Periodic,
            _ => Mode::Threaded,
        },
    };
    Ok((spec, PathBuf::from(pack)))
}
