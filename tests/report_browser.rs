//! The report as a person sees it: a tiny run's `report/index.html` opened in headless
//! Chromium (the system's package; `.ci/run` installs it when missing), every image loaded and
//! no table wider than the page's column, and a screenshot taken the same way.

mod common;

use std::path::Path;
use std::process::Command;

use common::{nerfsv, s};

/// The system's Chromium: `chromium` or `chromium-browser` on the PATH.
fn chromium() -> Option<&'static str> {
    ["chromium", "chromium-browser"]
        .into_iter()
        .find(|c| Command::new(c).arg("--version").output().is_ok_and(|o| o.status.success()))
}

/// Runs headless Chromium on `args` (a file URL last), returning stdout.
fn headless(browser: &str, args: &[&str]) -> String {
    let out = Command::new(browser)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--virtual-time-budget=10000"])
        .args(args)
        .output()
        .expect("run chromium");
    assert!(out.status.success(), "chromium failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A checker page beside the report: the report's page with a script that, once everything
/// has loaded, counts the images that did not load, the tables wider than their container and
/// the failure views (animated PNGs) that loaded, and writes the counts into the page for
/// `--dump-dom`.
fn checker(report: &Path) -> std::path::PathBuf {
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    let script = r#"<script>
window.addEventListener('load', () => {
  const imgs = [...document.images];
  const broken = imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.getAttribute('src'));
  const wide = [...document.querySelectorAll('table')].filter(t => t.scrollWidth > t.parentElement.clientWidth + 1);
  const pre = document.createElement('pre');
  pre.id = 'check';
  const views = imgs.filter(i => i.src.endsWith('view.png') && i.complete && i.naturalWidth > 0);
  pre.textContent = `images=${imgs.length} broken=${broken.length} wide_tables=${wide.length} views=${views.length} broken_list=${broken.join(';')}`;
  document.body.appendChild(pre);
});
</script></body>"#;
    let path = report.join("check.html");
    std::fs::write(&path, html.replace("</body>", script)).unwrap();
    path
}

#[test]
fn the_report_loads_every_image_and_no_table_overflows_in_a_real_browser() {
    let Some(browser) = chromium() else {
        if std::env::var_os("NERFSV_SKIP_BROWSER").is_some() {
            eprintln!("no chromium: skipped (NERFSV_SKIP_BROWSER)");
            return;
        }
        panic!("the report's browser test needs Chromium (`apt-get install chromium`; .ci/run installs it)");
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("run.toml");
    std::fs::write(
        &cfg,
        "scene = \"monolith\"\ncells_per_metre = 10.0\ntrain_steps = 3\n[dataset]\nwidth = 16\nheight = 16\n\
         train = 4\nval = 1\ntest = 1\nsupersample = 1\n[train]\nbatch_rays = 256\n[sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n\
         [stress.monte_carlo]\nrollouts = 3\n[stress.cem]\nm = 3\nm_elite = 1\nk_max = 1\nis_samples = 2\n[stress.subset]\nsamples = 10\nmax_levels = 2\n\
         [uq]\nmax_rays = 16\nperturbations = 1\nlm_iterations = 2\nonline_rays = 64\nonline_bla_rays = 16\n\
         [uq_offline]\nbla_images_per_split = 1\n[online]\nmethods = [\"ga\"]\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let (ok, _, err) = nerfsv(&["run", s(&cfg), "--out", s(&out)]);
    assert!(ok, "{err}");
    let report = out.join("report");
    let check = checker(&report);
    let dom = headless(browser, &["--dump-dom", &format!("file://{}", check.display())]);
    let line = dom
        .split("<pre id=\"check\">")
        .nth(1)
        .and_then(|t| t.split("</pre>").next())
        .unwrap_or_else(|| panic!("the check did not run: {}", &dom[dom.len().saturating_sub(500)..]));
    let field = |k: &str| -> usize {
        line.split_whitespace().find_map(|w| w.strip_prefix(&format!("{k}="))).unwrap().parse().unwrap()
    };
    assert!(field("images") >= 8, "{line}");
    assert_eq!(field("broken"), 0, "images that did not load: {line}");
    assert_eq!(field("wide_tables"), 0, "tables wider than the page: {line}");
    // The tiny run's searches find no crash (its drone leaves the grid first), so the drone's
    // view is checked on a flight of its model: `nerfsv fly`'s view.png (the same writer as the
    // report's failure views) loads as an image in the browser.
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    assert_eq!(field("views"), html.matches("view.png\"").count(), "{line}");
    let fly = dir.path().join("fly");
    let model = out.join("nerf/checkpoint.safetensors");
    let field_path = out.join("nerf_collision/nerf_sdf.safetensors");
    let (ok, _, err) = nerfsv(&[
        "fly",
        "--scene",
        "monolith",
        "--world",
        "gt",
        "--model",
        s(&model),
        "--nerf-field",
        s(&field_path),
        "--config",
        s(&cfg),
        "--out",
        s(&fly),
    ]);
    assert!(ok, "{err}");
    std::fs::write(fly.join("index.html"), "<html><body><img src=\"view.png\"></body></html>").unwrap();
    let dom = headless(browser, &["--dump-dom", &format!("file://{}", checker(&fly).display())]);
    assert!(dom.contains("images=1 broken=0 wide_tables=0 views=1"), "{}", &dom[dom.len().saturating_sub(300)..]);

    // A screenshot, as the README's was taken: a PNG of the requested size.
    let shot = dir.path().join("shot.png");
    headless(
        browser,
        &[
            "--window-size=1200,1500",
            &format!("--screenshot={}", shot.display()),
            &format!("file://{}", report.join("index.html").display()),
        ],
    );
    let bytes = std::fs::read(&shot).unwrap();
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let info = decoder.read_info().unwrap();
    assert_eq!((info.info().width, info.info().height), (1200, 1500));
}
