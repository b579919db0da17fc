"""LaTeX ingestion: \\input chains, macros, numbering, floats, algorithms, .bib/.bbl, tarballs."""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

import pytest

from nerfify_ns.paper import MissingLatexFileError, UnsafeArchiveError, UnsupportedInputError, ingest
from nerfify_ns.paper.latex_source import collect_macros, expand_macros

MAIN = r"""\documentclass{article}
\newcommand{\vx}{\mathbf{x}}
\newcommand{\norm}[1]{\lVert #1\rVert}
\def\method{TinyNeRF}
\title{\method: Radiance Fields in a Test}
\author{Ada Lovelace \and Alan Turing}
\begin{document}
\maketitle
\begin{abstract}
We present \method, a neural radiance field for novel view synthesis.
\end{abstract}
\section{Introduction}
NeRF~\cite{mildenhall2020nerf} renders rays. % a comment that must vanish
\input{sections/method}
\appendix
\section{Extra}
More.
\bibliography{refs}
\end{document}
"""
METHOD = r"""\section{Method}\label{sec:method}
We render with Eq.~\eqref{eq:render}, where $\norm{\vx}$ is bounded.
\input{sections/details}
"""
DETAILS = r"""\begin{equation}
C = \sum_i T_i \alpha_i c_i \label{eq:render}
\end{equation}
\begin{align}
a &= b \nonumber \\
c &= d \label{eq:two}\\
e &= f
\end{align}
\begin{equation*}
z = 1
\end{equation*}
\subsection{Details}
We use a learning rate of $5\times 10^{-4}$, a batch size of 4096 rays and Eq.~\eqref{eq:two} of Sec.~\ref{sec:method} \cite{muller2022instant,barron2022mip}.
\begin{table}\caption{Results.}\label{tab:res}
\begin{tabular}{lcc}\toprule Method & PSNR & SSIM \\ \midrule NeRF & 31.0 & 0.95 \\ Ours & 32.1 & 0.96 \\ \bottomrule\end{tabular}
\end{table}
\begin{figure}\includegraphics{a.png}\caption{Overview of \method.}\label{fig:overview}\end{figure}
\begin{algorithm}\caption{Training loop}\label{alg:train}
\begin{algorithmic}
\Require images
\For{$i = 1$ to $N$}
\State sample rays
\EndFor
\end{algorithmic}
\end{algorithm}
"""  # noqa: E501
BIB = r"""@inproceedings{mildenhall2020nerf,
  title={{NeRF}: Representing Scenes as Neural Radiance Fields for View Synthesis},
  author={Mildenhall, Ben and Srinivasan, Pratul P. and Tancik, Matthew},
  booktitle={ECCV}, year={2020}, eprint={2003.08934}, archivePrefix={arXiv}
}
@article{muller2022instant, title = "Instant Neural Graphics Primitives", author = {M{\"u}ller, Thomas},
  journal = {ACM TOG}, year = 2022, doi = {10.1145/3528223.3530127}}
@misc{unused, title={Never Cited}, year={1999}}
@article{barron2022mip, title={Mip-NeRF 360}, author={Barron, Jonathan T.}, journal={arXiv preprint arXiv:2111.12077}, year={2022}}
"""  # noqa: E501


def write_tree(root: Path, with_details: bool = True) -> Path:
    (root / "sections").mkdir(parents=True)
    (root / "main.tex").write_text(MAIN)
    (root / "sections" / "method.tex").write_text(METHOD)
    if with_details:
        (root / "sections" / "details.tex").write_text(DETAILS)
    (root / "refs.bib").write_text(BIB)
    (root / "macros_only.tex").write_text(r"\newcommand{\foo}{bar}")  # not the main file
    return root


@pytest.fixture(scope="module")
def tree_doc(tmp_path_factory):
    return ingest(write_tree(tmp_path_factory.mktemp("tex") / "paper"))


def test_title_authors_abstract_with_macros(tree_doc):
    assert tree_doc.kind == "latex"
    assert tree_doc.title == "TinyNeRF: Radiance Fields in a Test"
    assert tree_doc.authors == ["Ada Lovelace", "Alan Turing"]
    assert tree_doc.abstract == "We present TinyNeRF, a neural radiance field for novel view synthesis."


def test_sections_follow_inputs_with_file_lines(tree_doc):
    heads = [(s.number, s.title) for s in tree_doc.sections]
    assert heads == [("1", "Introduction"), ("2", "Method"), ("2.1", "Details"), ("A", "Extra")]
    method = tree_doc.sections[1]
    assert (method.loc.file, method.loc.line) == ("sections/method.tex", 1)
    assert "comment" not in tree_doc.text()


def test_macros_with_arguments_and_refs(tree_doc):
    para = tree_doc.sections[1].paragraphs[0].text
    assert para == r"We render with Eq. (1), where $\lVert \mathbf{x}\rVert$ is bounded."
    details = tree_doc.sections[2].paragraphs[0].text
    assert "Eq. (2) of Sec. 2" in details and "[muller2022instant, barron2022mip]" in details


def test_equation_numbering(tree_doc):
    eqs = [(e.number, e.label, e.latex) for e in tree_doc.equations]
    assert eqs[0] == ("1", "eq:render", r"C = \sum_i T_i \alpha_i c_i")
    assert eqs[1][:2] == ("2", "eq:two") and "a &= b" in eqs[1][2] and "c &= d" in eqs[1][2]
    assert eqs[2][:2] == ("3", "") and eqs[3] == ("", "", "z = 1")
    assert tree_doc.equations[0].loc.file == "sections/details.tex" and tree_doc.equations[0].loc.line == 1


def test_floats_and_algorithm(tree_doc):
    assert [(c.kind, c.number, c.label) for c in tree_doc.captions] == [
        ("table", "1", "tab:res"), ("figure", "1", "fig:overview")]
    assert tree_doc.captions[1].text == "Figure 1: Overview of TinyNeRF."
    assert tree_doc.result_tables[0].rows == [["Method", "PSNR", "SSIM"], ["NeRF", "31.0", "0.95"],
                                              ["Ours", "32.1", "0.96"]]
    alg = tree_doc.algorithms[0]
    assert alg.number == "1" and alg.title == "Training loop"
    assert alg.lines[1:] == ["require images", "for $i = 1$ to $N$", "sample rays", "endfor"]


def test_bib_references_cited_only(tree_doc):
    refs = {r.key: r for r in tree_doc.references}
    assert list(refs) == ["mildenhall2020nerf", "muller2022instant", "barron2022mip"]
    nerf = refs["mildenhall2020nerf"]
    assert nerf.title.startswith("NeRF: Representing") and nerf.year == 2020 and nerf.arxiv == "2003.08934"
    assert nerf.authors[0] == "Mildenhall, Ben" and nerf.venue == "ECCV"
    assert refs["muller2022instant"].doi == "10.1145/3528223.3530127"
    assert refs["barron2022mip"].arxiv == "2111.12077"
    assert [c.keys for c in tree_doc.citations] == [["mildenhall2020nerf"], ["muller2022instant", "barron2022mip"]]


def test_hyperparameters_from_latex(tree_doc):
    hp = {h.name: h.value for h in tree_doc.hyperparameters}
    assert hp["learning_rate"] == pytest.approx(5e-4) and hp["batch_size"] == 4096


def test_bbl_is_used(tmp_path):
    root = write_tree(tmp_path / "p")
    (root / "main.bbl").write_text(r"""\begin{thebibliography}{2}
\bibitem{mildenhall2020nerf} B.~Mildenhall and P.~Srinivasan.
\newblock NeRF: Representing scenes.
\newblock In {\em ECCV}, 2020.
\bibitem{zhang2020} K.~Zhang, G.~Riegler.
\newblock NeRF++: Analyzing and improving neural radiance fields.
\newblock arXiv:2010.07492, 2020.
\end{thebibliography}""")
    refs = ingest(root).references
    assert [r.key for r in refs] == ["mildenhall2020nerf", "zhang2020"]
    assert refs[0].arxiv == "2003.08934"  # enriched from the .bib
    assert refs[1].title == "NeRF++: Analyzing and improving neural radiance fields" and refs[1].arxiv == "2010.07492"


def test_single_tex_file_and_missing_input(tmp_path):
    root = write_tree(tmp_path / "p", with_details=False)
    with pytest.raises(MissingLatexFileError, match="sections/details"):
        ingest(root / "main.tex")


def test_macro_expansion_unit():
    macros, rest = collect_macros(r"\newcommand{\pair}[2][a]{(#1,#2)}\renewcommand\R{\mathbb{R}}" "\n"
                                  r"x \pair{b} \pair[c]{d} \R^3 \Rx")
    assert expand_macros(rest, macros).strip() == r"x (a,b) (c,d) \mathbb{R}^3 \Rx"


def _tar(path: Path, files: dict[str, str]) -> Path:
    with tarfile.open(path, "w:gz") as tar:
        for name, text in files.items():
            data = text.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return path


def test_tarball(tmp_path):
    path = _tar(tmp_path / "src.tar.gz", {"main.tex": MAIN, "sections/method.tex": METHOD,
                                          "sections/details.tex": DETAILS, "refs.bib": BIB})
    doc = ingest(path)
    assert doc.title.startswith("TinyNeRF") and len(doc.equations) == 4 and len(doc.references) == 3


@pytest.mark.parametrize("bad", ["../evil.tex", "/abs/evil.tex"])
def test_unsafe_tarball(tmp_path, bad):
    path = _tar(tmp_path / "src.tgz", {"main.tex": MAIN, bad: "x"})
    with pytest.raises(UnsafeArchiveError, match="escape"):
        ingest(path)
    assert not (tmp_path / "evil.tex").exists()


def test_folder_without_main(tmp_path):
    (tmp_path / "only.tex").write_text(r"\section{A}")
    with pytest.raises(UnsupportedInputError, match="documentclass"):
        ingest(tmp_path)
