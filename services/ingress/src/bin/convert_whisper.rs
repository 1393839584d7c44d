//! Converts a CTranslate2 Whisper model (`model.bin` + `config.json`) into
//! candle's Whisper layout (`model.safetensors` + `config.json`).
//! Run once by deploy/models.d/50-whisper.sh.

use std::path::PathBuf;

use clap::Parser;

#[derive(Parser)]
#[command(name = "vlnav-convert-whisper")]
struct Cli {
    /// CTranslate2 `model.bin`.
    model_bin: PathBuf,
    /// CTranslate2 `config.json` (suppressed token ids).
    config_json: PathBuf,
    /// Output directory for `model.safetensors` and `config.json`.
    out_dir: PathBuf,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let (n, cfg) = vlnav_ingress::convert::convert_files(&cli.model_bin, &cli.config_json, &cli.out_dir)?;
    println!(
        "wrote {n} tensors to {}: d_model {}, {} encoder + {} decoder layers, vocabulary {}",
        cli.out_dir.join("model.safetensors").display(),
        cfg.d_model,
        cfg.encoder_layers,
        cfg.decoder_layers,
        cfg.vocab_size
    );
    Ok(())
}
