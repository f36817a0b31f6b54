//! `nerfsv completions SHELL`: the shell's completion script for every subcommand, flag and
//! choice, generated from the same definitions the parser uses (`clap_complete`).

use clap::{Args, CommandFactory};
use clap_complete::Shell;

#[derive(Args)]
pub struct CompletionsArgs {
    /// The shell: bash, zsh, fish, elvish or powershell. Bash: `nerfsv completions bash >
    /// ~/.local/share/bash-completion/completions/nerfsv`; zsh: into a folder of `$fpath` as
    /// `_nerfsv`; fish: `~/.config/fish/completions/nerfsv.fish`.
    pub shell: Shell,
}

/// Prints the completion script of `C`'s commands, named `nerfsv`.
pub fn run<C: CommandFactory>(args: CompletionsArgs) -> anyhow::Result<()> {
    let mut command = C::command();
    clap_complete::generate(args.shell, &mut command, "nerfsv", &mut std::io::stdout());
    Ok(())
}
