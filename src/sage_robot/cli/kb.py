"""`sage kb ...`: ingest, search, list and delete documents; serve the KB's HTTP API."""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sage_robot.core.errors import SageError

if TYPE_CHECKING:
    from sage_robot.kb.progress import IngestProgress, IngestRun

PROGRESS_S = 0.25  # how often the progress bar is redrawn (s)
EXIT_CANCELLED = 130  # 128 + SIGINT, as a shell reports Ctrl-C


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("kb", help="knowledge base: ingest, search, list, delete, serve")
    p.set_defaults(help_parser=p)
    ksub = p.add_subparsers(dest="kb_command", metavar="COMMAND")

    q = ksub.add_parser("ingest", help="add files or folders (PDF, DOCX, HTML, Markdown, text)")
    q.add_argument("paths", nargs="+", type=Path, help="files or folders (searched recursively)")
    q.add_argument("--json", action="store_true", help="print one JSON line per file")
    q.set_defaults(func=cmd_ingest)

    q = ksub.add_parser("search", help="ask a question; print the best passages")
    q.add_argument("query", help="the question")
    q.add_argument("--top-k", type=int, default=None, help="passages to show (default: profile)")
    q.add_argument("--json", action="store_true", help="print the seed-style JSON answer")
    q.set_defaults(func=cmd_search)

    q = ksub.add_parser("list", help="list the documents")
    q.add_argument("--json", action="store_true", help="print JSON")
    q.set_defaults(func=cmd_list)

    q = ksub.add_parser("delete", help="remove a document and its passages")
    q.add_argument("id", type=int, help="document id (see `sage kb list`)")
    q.set_defaults(func=cmd_delete)

    q = ksub.add_parser("serve", help="serve the KB's HTTP API and admin page alone")
    q.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    q.add_argument("--port", type=int, default=8004, help="port (default 8004, as the seed)")
    q.set_defaults(func=cmd_serve)


def _open(args: argparse.Namespace, load_corpus: bool = True) -> Any:
    from sage_robot.core.config import load_profile
    from sage_robot.kb.service import KbService

    settings = load_profile(args.profile)
    try:
        service = KbService.from_settings(settings.kb)
    except ImportError as exc:
        raise SageError(
            f"the knowledge base needs {exc.name}; install it with: pip install 'sage-robot[kb]'"
        ) from None
    if load_corpus and settings.kb.load_corpus:
        service.ensure_corpus()
    return settings, service


def cmd_ingest(args: argparse.Namespace) -> int:
    """Ingest in a worker thread; Ctrl-C cancels (the document being read is not stored, the
    ones before it are), a second Ctrl-C quits at once (an unfinished write rolls back)."""
    from sage_robot.kb.service import PendingDocument, expand_paths

    _, service = _open(args, load_corpus=False)
    docs = [PendingDocument(p.name, str(p.resolve()), path=p) for p in expand_paths(args.paths)]
    run = service.begin_ingest(len(docs))
    results: list[Any] = []
    worker = threading.Thread(
        target=lambda: results.extend(service.ingest_documents(docs, run)), name="kb-ingest", daemon=True
    )
    show = not args.json and (len(docs) > 1 or sys.stderr.isatty())
    with _ProgressBar(len(docs), show) as bar:
        worker.start()
        _wait(worker, run, bar)
    service.close()
    failed = [r for r in results if r.status == "failed"]
    for r in results:
        if args.json:
            print(json.dumps(r.as_dict()))
        elif r.ok:
            print(f"{r.status:9} #{r.document_id:<4} {r.chunks:4} chunks  {r.source}")
        else:
            print(f"{r.status:9} {r.message}", file=sys.stderr)
    done = sum(r.ok for r in results)
    if not args.json:
        end = "; cancelled" if run.cancelled else ""
        print(f"{done} of {len(results)} files ingested{end}", file=sys.stderr)
    return EXIT_CANCELLED if run.cancelled else 1 if failed else 0


def _wait(worker: threading.Thread, run: IngestRun, bar: _ProgressBar) -> None:
    """Until the worker ends. The first Ctrl-C cancels the run, the second one raises."""
    while True:
        try:
            while worker.is_alive():
                worker.join(PROGRESS_S)
                bar.show(run.snapshot())
            return
        except KeyboardInterrupt:
            if run.cancelled:
                raise
            run.cancel()
            print("\nsage kb: cancelling; the document being read will not be stored "
                  "(Ctrl-C again to quit now)", file=sys.stderr)


class _ProgressBar:
    """A tqdm bar of documents with the current one's chunks, fed progress snapshots."""

    def __init__(self, total: int, show: bool) -> None:
        from tqdm import tqdm

        self._bar = tqdm(total=total, unit="file", disable=not show, file=sys.stderr)

    def show(self, p: IngestProgress) -> None:
        self._bar.n = p.documents_done
        if p.current:
            where = f"{p.current[-30:]} {p.chunks_done}/{p.chunks_total} chunks"
            self._bar.set_postfix_str(where, refresh=False)
        self._bar.refresh()

    def __enter__(self) -> _ProgressBar:
        return self

    def __exit__(self, *exc: object) -> None:
        self._bar.close()


def cmd_search(args: argparse.Namespace) -> int:
    from sage_robot.kb.service import passages_as_answer

    settings, service = _open(args)
    top_k = args.top_k or settings.kb.top_k
    passages = service.search(args.query, top_k)
    service.close()
    if args.json:
        print(json.dumps(passages_as_answer(args.query, passages)))
        return 0
    for i, p in enumerate(passages, 1):
        print(f"{i}. {p.title} — {p.section}  (score {p.score:.4f}, {p.source})")
        print(f"   {p.text}\n")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    _, service = _open(args)
    docs = service.list_documents()
    service.close()
    if args.json:
        print(json.dumps({"documents": docs}))
        return 0
    for d in docs:
        print(f"#{d['id']:<4} {d['chunks']:4} chunks  {d['title'][:40]:40}  {d['source']}")
    print(f"{len(docs)} documents", file=sys.stderr)
    return 0


def cmd_delete(args: argparse.Namespace) -> int:
    _, service = _open(args, load_corpus=False)
    found = service.delete_document(args.id)
    service.close()
    if not found:
        raise SageError(f"no document with id {args.id} (see `sage kb list`)")
    print(f"deleted document #{args.id}")
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from sage_robot.core.config import read_secret
    from sage_robot.kb.serve import OPERATOR_SECRET, create_app

    settings, service = _open(args)
    password = read_secret(OPERATOR_SECRET, settings.secrets_file or None)
    if password is None:
        print(f"sage kb: {OPERATOR_SECRET} is not set: uploads and deletes are refused",
              file=sys.stderr)
    app = create_app(service, password, settings.email, settings.secrets_file or None)
    print(f"knowledge base on http://{args.host}:{args.port}/kb/admin", file=sys.stderr)
    from sage_robot.web.app import body_limit
    from sage_robot.web.guard import RequestGuard
    from sage_robot.web.node import proxy_options

    web = settings.web
    app.add_middleware(
        RequestGuard,
        routes=lambda: app.router.routes,
        allowed_origins=lambda: web.allowed_origins,
        body_limit=body_limit,
    )
    uvicorn.run(
        app, host=args.host, port=args.port, log_level="warning", **proxy_options(web.trusted_proxies)
    )
    service.close()
    return 0
