from textile_fenicsx.cli import main

raise SystemExit(main())
