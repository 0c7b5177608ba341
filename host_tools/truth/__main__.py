from host_tools.truth.cli import main

raise SystemExit(main())
